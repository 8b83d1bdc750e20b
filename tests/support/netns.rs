//! A network namespace with only loopback for a child process, so DDS or ROS 1 traffic
//! of tests and benchmarks cannot leave the machine, and a hard time limit on it.

/// Set in a process that `loopback_netns` started.
pub const IN_LOOPBACK_NETNS: &str = "FERROSA_IN_NETNS";

/// A command that runs `exe args…` in a new network namespace whose only interface is
/// loopback (`unshare -n`, then `ip link set lo up`), killed after `limit_s` seconds.
/// Needs root (or a user namespace), util-linux and iproute2; the child sees
/// `IN_LOOPBACK_NETNS` set.
pub fn loopback_netns(
    exe: &std::path::Path,
    args: impl IntoIterator<Item = impl AsRef<std::ffi::OsStr>>,
    limit_s: u32,
) -> std::process::Command {
    let mut cmd = std::process::Command::new("unshare");
    cmd.args([
        "-n",
        "sh",
        "-c",
        "ip link set lo up && exec timeout -k 5 \"$@\"",
        "sh",
    ])
    .arg(limit_s.to_string())
    .arg(exe)
    .args(args)
    .env(IN_LOOPBACK_NETNS, "1");
    cmd
}

/// Whether this process runs inside such a namespace.
pub fn inside() -> bool {
    std::env::var_os(IN_LOOPBACK_NETNS).is_some()
}
