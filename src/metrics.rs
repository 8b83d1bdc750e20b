//! Process and machine measurements for `--stats` and the benchmarks: peak resident
//! memory, the CPU model. Linux `/proc` only; elsewhere the figures are absent, not wrong.

/// Peak resident set size (VmHWM) in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    proc_status_kib("VmHWM:").map(|k| k * 1024)
}

/// Current resident set size (VmRSS) in bytes.
pub fn rss_bytes() -> Option<u64> {
    proc_status_kib("VmRSS:").map(|k| k * 1024)
}

fn proc_status_kib(key: &str) -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// The CPU model name, as /proc/cpuinfo gives it.
pub fn cpu_model() -> Option<String> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    info.lines()
        .find_map(|l| l.strip_prefix("model name"))
        .map(|v| v.trim_start_matches([' ', '\t', ':']).trim().to_string())
}

pub fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn rss_is_readable_on_linux() {
        if cfg!(target_os = "linux") {
            // Current first: the peak read afterwards covers it even if memory grew.
            let now = super::rss_bytes().unwrap();
            let peak = super::peak_rss_bytes().unwrap();
            assert!(peak >= now && now > 0);
        }
    }
}
