//! How much memory a level may take on this machine (ARCHITECTURE §3.8): the
//! smaller of the host's available memory and what the process's cgroup still
//! allows, so a run in a container stops with an error instead of being killed.

/// Bytes this process can still allocate: `MemAvailable` of `/proc/meminfo`,
/// capped by the cgroup limit minus its usage (v2 `memory.max` and
/// `memory.current`, or v1 `memory.limit_in_bytes` and `memory.usage_in_bytes`).
/// `None` where none of these can be read.
pub fn available_bytes() -> Option<u64> {
    let read = |p: &str| std::fs::read_to_string(p).ok();
    let host = read("/proc/meminfo").and_then(|s| mem_available(&s));
    let cgroup = cgroup_room(
        read("/sys/fs/cgroup/memory.max")
            .or_else(|| read("/sys/fs/cgroup/memory/memory.limit_in_bytes")),
        read("/sys/fs/cgroup/memory.current")
            .or_else(|| read("/sys/fs/cgroup/memory/memory.usage_in_bytes")),
    );
    match (host, cgroup) {
        (Some(h), Some(c)) => Some(h.min(c)),
        (h, c) => h.or(c),
    }
}

/// `MemAvailable` of a `/proc/meminfo` text, in bytes.
pub fn mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

/// Room left under a cgroup limit: `limit − usage`; `None` for no limit
/// (`max`, or v1's huge "unlimited" value) or unreadable files.
pub fn cgroup_room(limit: Option<String>, usage: Option<String>) -> Option<u64> {
    let limit: u64 = limit?.trim().parse().ok()?;
    if limit >= 1 << 60 {
        return None;
    }
    let usage: u64 = usage.and_then(|u| u.trim().parse().ok()).unwrap_or(0);
    Some(limit.saturating_sub(usage))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_meminfo_and_cgroup_limits() {
        let m = "MemTotal:       24000000 kB\nMemFree: 1 kB\nMemAvailable:   2000 kB\n";
        assert_eq!(mem_available(m), Some(2000 * 1024));
        assert_eq!(mem_available("MemTotal: 5 kB\n"), None);
        assert_eq!(cgroup_room(Some("max\n".into()), Some("10".into())), None);
        assert_eq!(
            cgroup_room(Some("1000\n".into()), Some("250\n".into())),
            Some(750)
        );
        assert_eq!(cgroup_room(Some("100".into()), Some("250".into())), Some(0));
        assert_eq!(
            cgroup_room(Some("9223372036854771712".into()), Some("1".into())),
            None
        );
        assert_eq!(cgroup_room(None, Some("1".into())), None);
    }

    #[test]
    fn this_machine_reports_some_memory() {
        if std::path::Path::new("/proc/meminfo").exists() {
            assert!(available_bytes().is_some_and(|b| b > 0));
        }
    }
}
