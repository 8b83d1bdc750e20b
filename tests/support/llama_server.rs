//! Upstream llama-server as the remote engine's peer: found where
//! `scripts/build-llama-cpp.sh llama-server` leaves it (or at `LLAMA_SERVER`), started on
//! loopback with a model file, stopped when dropped, and never alive longer than 15
//! minutes whatever happens to the process that started it (`timeout`).

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The llama-server binary: `LLAMA_SERVER`, else the build script's output, if built.
pub fn binary() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("LLAMA_SERVER") {
        return Some(PathBuf::from(p));
    }
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("target/llama-bench/llama_cpp_python-0.3.36/vendor/llama.cpp/build/bin/llama-server");
    p.exists().then_some(p)
}

/// A running server.
pub struct Server {
    child: Child,
    /// `http://127.0.0.1:PORT`.
    pub url: String,
    log: PathBuf,
}

impl Server {
    /// Start `bin` serving `model` with `threads` threads and one slot of `ctx` tokens;
    /// returns once the model is loaded (`/health` answers 200), panics with the server's
    /// log if it is not within 120 s.
    pub fn start(bin: &Path, model: &Path, threads: usize, ctx: usize) -> Server {
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free loopback port")
            .port();
        let log = std::env::temp_dir().join(format!("ferrosa-llama-server-{port}.log"));
        let child = Command::new("timeout")
            .args(["-s", "TERM", "900"])
            .arg(bin)
            .arg("-m")
            .arg(model)
            .args(["--host", "127.0.0.1", "--port", &port.to_string()])
            .args([
                "-c",
                &ctx.to_string(),
                "-t",
                &threads.to_string(),
                "-np",
                "1",
            ])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).expect("the server's log file"))
            .spawn()
            .expect("timeout (coreutils) and llama-server");
        let mut s = Server {
            child,
            url: format!("http://127.0.0.1:{port}"),
            log,
        };
        s.wait_ready();
        s
    }

    fn wait_ready(&mut self) {
        let start = Instant::now();
        let addr = self.url.trim_start_matches("http://").to_string();
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("llama-server exited ({status}): {}", self.log_text());
            }
            if let Ok(mut c) = TcpStream::connect(&addr) {
                let _ = write!(
                    c,
                    "GET /health HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
                );
                let mut answer = String::new();
                let _ = c.read_to_string(&mut answer);
                if answer.starts_with("HTTP/1.1 200") {
                    return;
                }
            }
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "llama-server not ready after 120 s: {}",
                self.log_text()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// What the server logged so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        // TERM, which `timeout` passes on; KILL after 5 s.
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let start = Instant::now();
        while matches!(self.child.try_wait(), Ok(None)) && start.elapsed() < Duration::from_secs(5)
        {
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.log);
    }
}
