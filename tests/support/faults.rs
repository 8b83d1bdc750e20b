//! The soak's faults (tests/soak.rs): foreign ROS 2 nodes, `peers/soak_peer.py` under
//! rclpy, started and killed as processes. A `Peer` is one such process, ready once its
//! endpoints exist; `Crashing` keeps `/soak_peer` running and kills it (SIGKILL, no
//! goodbye on DDS) whenever a call to its slow service has reached it. What the peers
//! do on ROS is in the script's own header; nothing here speaks ROS.

use std::io::{BufRead, BufReader, Lines};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Seconds a peer process may live (the soak's namespace has a limit above it).
const PEER_LIMIT_S: &str = "400";

/// A `soak_peer.py` process under `timeout`, ready (its endpoints exist), with its
/// Python's pid and its stdout.
pub struct Peer {
    child: Child,
    pub pid: u32,
    pub out: Lines<BufReader<ChildStdout>>,
    pub stdin: Option<ChildStdin>,
    /// Killed already: its pid may belong to another process by now.
    ended: bool,
}

impl Peer {
    pub fn start(args: &[&str]) -> Peer {
        let mut child = Command::new("timeout")
            .args(["-s", "KILL", PEER_LIMIT_S])
            .arg(crate::ros::rclpy_python())
            .arg(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/peers/soak_peer.py"))
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("starting soak_peer.py {args:?}: {e}"));
        let stdin = child.stdin.take();
        let mut out = BufReader::new(child.stdout.take().expect("piped stdout")).lines();
        let pid = loop {
            match out.next() {
                Some(Ok(line)) => {
                    if let Some(pid) = line.strip_prefix("ready ") {
                        break pid.trim().parse().expect("a pid after ready");
                    }
                }
                _ => panic!("soak_peer.py {args:?} ended before it was ready"),
            }
        };
        Peer {
            child,
            pid,
            out,
            stdin,
            ended: false,
        }
    }

    /// SIGKILL to the Python process: no goodbye on DDS, as a crash or a power cut.
    pub fn kill(&mut self) {
        if std::mem::replace(&mut self.ended, true) {
            return;
        }
        // `timeout` ends only after the Python it started: while it runs, the pid is
        // still that Python's.
        if matches!(self.child.try_wait(), Ok(None)) {
            kill(self.pid);
        }
        let _ = self.child.wait();
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        self.kill();
    }
}

fn kill(pid: u32) {
    let _ = Command::new("kill")
        .args(["-KILL", &pid.to_string()])
        .stderr(Stdio::null())
        .status();
}

/// `/soak_peer`, killed whenever a call to its slow service arrives, and started again.
pub struct Crashing {
    stop: Arc<AtomicBool>,
    /// The running peer's Python (none while it starts or after it ended).
    pid: Arc<Mutex<Option<u32>>>,
    kills: Arc<AtomicUsize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Crashing {
    pub fn start() -> Crashing {
        let stop = Arc::new(AtomicBool::new(false));
        let pid = Arc::new(Mutex::new(None));
        let kills = Arc::new(AtomicUsize::new(0));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let thread = {
            let (stop, pid, kills) = (stop.clone(), pid.clone(), kills.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::SeqCst) {
                    let mut peer = Peer::start(&["serve"]);
                    *pid.lock().unwrap() = Some(peer.pid);
                    let _ = ready_tx.send(());
                    // Mid-call: the request has arrived, the reply is 30 s away.
                    let killed = loop {
                        match peer.out.next() {
                            Some(Ok(line)) if line == "slow call" => break true,
                            Some(Ok(_)) => continue,
                            _ => break false,
                        }
                    };
                    // Forgotten before it is killed: `end` kills only a live pid.
                    *pid.lock().unwrap() = None;
                    peer.kill();
                    if killed && !stop.load(Ordering::SeqCst) {
                        kills.fetch_add(1, Ordering::SeqCst);
                    }
                }
            })
        };
        ready_rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the /soak_peer node started");
        Crashing {
            stop,
            pid,
            kills,
            thread: Some(thread),
        }
    }

    /// Stop starting it again and kill it; how many times it was killed mid-call.
    pub fn end(&mut self) -> usize {
        self.stop.store(true, Ordering::SeqCst);
        let mut killed = None;
        while self.thread.as_ref().is_some_and(|t| !t.is_finished()) {
            // Under the lock: the thread forgets the pid before it kills the process.
            if let Some(pid) = *self.pid.lock().unwrap() {
                if killed != Some(pid) {
                    kill(pid);
                    killed = Some(pid);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.kills.load(Ordering::SeqCst)
    }
}

impl Drop for Crashing {
    fn drop(&mut self) {
        self.end();
    }
}
