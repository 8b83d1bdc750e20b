//! Process and machine measurements for `--stats` and the benchmarks: peak resident
//! memory and what it is made of, the CPU model. Linux `/proc` only; elsewhere the figures are absent, not wrong.

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

/// Resident memory by what backs it, from `/proc/self/smaps`: each mapped file (the
/// model's weights, the executable and its libraries) and the anonymous rest (heap,
/// stacks, the KV cache and compute buffers a runtime allocates), in bytes, largest
/// first.
pub fn resident_parts() -> Option<Vec<(String, u64)>> {
    parse_smaps(&std::fs::read_to_string("/proc/self/smaps").ok()?)
}

fn parse_smaps(smaps: &str) -> Option<Vec<(String, u64)>> {
    let mut parts: std::collections::BTreeMap<String, u64> = Default::default();
    let mut current = String::new();
    for line in smaps.lines() {
        let mut fields = line.split_whitespace();
        let Some(first) = fields.next() else { continue };
        if first.contains('-') && first.chars().all(|c| c.is_ascii_hexdigit() || c == '-') {
            // A mapping's header: address perms offset dev inode [path].
            let path = fields.nth(4).unwrap_or("");
            current = if path.starts_with('/') {
                path.to_string()
            } else {
                "anonymous".to_string()
            };
        } else if first == "Rss:" {
            let kib: u64 = fields.next()?.parse().ok()?;
            *parts.entry(current.clone()).or_default() += kib * 1024;
        }
    }
    let mut out: Vec<(String, u64)> = parts.into_iter().filter(|(_, b)| *b > 0).collect();
    out.sort_by_key(|b| std::cmp::Reverse(b.1));
    Some(out)
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
    fn resident_memory_is_split_by_what_backs_it() {
        let smaps = "\
55d0-55e0 r-xp 00000000 08:01 123 /usr/bin/prog
Size:                 64 kB
Rss:                  40 kB
7f00-7f10 rw-p 00000000 00:00 0 
Rss:                 100 kB
7f20-7f30 r--s 00000000 08:01 9 /models/m.gguf
Rss:                 300 kB
7f40-7f50 rw-p 00000000 00:00 0 [heap]
Rss:                  20 kB
7f60-7f70 r--p 00000000 08:01 123 /usr/bin/prog
Rss:                   8 kB
";
        let parts = super::parse_smaps(smaps).unwrap();
        assert_eq!(
            parts,
            [
                ("/models/m.gguf".to_string(), 300 * 1024),
                ("anonymous".to_string(), 120 * 1024),
                ("/usr/bin/prog".to_string(), 48 * 1024),
            ]
        );
        if cfg!(target_os = "linux") {
            let live = super::resident_parts().unwrap();
            assert!(live.iter().any(|(p, _)| p == "anonymous"), "{live:?}");
        }
    }

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
