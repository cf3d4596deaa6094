//! One memory budget for the whole worker (ARCHITECTURE §4.5).
//!
//! Every allocation a request causes is reserved here first, atomically, and
//! released when the memory is freed: level planes and positions while a level
//! is held, a range's vectors and keys while it is assigned, and the transient
//! buffers of a call (the planes of a level being received, a search batch's
//! queries, answers and top-k lists, a calibration's vectors). A reservation
//! that does not fit is RESOURCE_EXHAUSTED before anything is allocated, so
//! jobs running side by side can never together exceed the cap.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use tonic::Status;

/// The worker-wide cap and what is reserved against it.
#[derive(Debug)]
pub(crate) struct Budget {
    limit: u64,
    used: AtomicU64,
    peak: AtomicU64,
}

/// Bytes reserved against a [`Budget`]; released when dropped.
#[derive(Debug)]
pub(crate) struct Reservation {
    budget: Arc<Budget>,
    bytes: u64,
}

impl Budget {
    pub(crate) fn new(limit: u64) -> Arc<Self> {
        Arc::new(Self {
            limit,
            used: AtomicU64::new(0),
            peak: AtomicU64::new(0),
        })
    }

    pub(crate) fn limit(&self) -> u64 {
        self.limit
    }

    /// Bytes reserved now.
    pub(crate) fn used(&self) -> u64 {
        self.used.load(Ordering::Acquire)
    }

    /// Most bytes ever reserved at once.
    pub(crate) fn peak(&self) -> u64 {
        self.peak.load(Ordering::Acquire)
    }

    /// Adds `bytes` to the reserved total if the total stays within the cap.
    fn take(&self, bytes: u64) -> Result<(), u64> {
        let mut used = self.used.load(Ordering::Acquire);
        loop {
            let next = used.checked_add(bytes).filter(|&n| n <= self.limit);
            let Some(next) = next else {
                return Err(used);
            };
            match self
                .used
                .compare_exchange_weak(used, next, Ordering::AcqRel, Ordering::Acquire)
            {
                Ok(_) => {
                    self.peak.fetch_max(next, Ordering::AcqRel);
                    return Ok(());
                }
                Err(now) => used = now,
            }
        }
    }

    fn give(&self, bytes: u64) {
        self.used.fetch_sub(bytes, Ordering::AcqRel);
    }

    /// Reserves `bytes` for `what`, or answers RESOURCE_EXHAUSTED naming the
    /// need, what is in use and the cap.
    pub(crate) fn reserve(self: &Arc<Self>, bytes: u64, what: &str) -> Result<Reservation, Status> {
        self.take(bytes)
            .map_err(|used| self.exhausted(bytes, used, what))?;
        Ok(Reservation {
            budget: self.clone(),
            bytes,
        })
    }

    fn exhausted(&self, bytes: u64, used: u64, what: &str) -> Status {
        Status::resource_exhausted(format!(
            "{what} needs {bytes} bytes but {used} of this worker's --max-memory {} are in use; retry later, send less, or give the worker more memory",
            self.limit
        ))
    }
}

impl Reservation {
    /// Changes the reservation to `bytes` (shrinking always succeeds).
    pub(crate) fn resize(&mut self, bytes: u64, what: &str) -> Result<(), Status> {
        if bytes > self.bytes {
            let more = bytes - self.bytes;
            self.budget
                .take(more)
                .map_err(|used| self.budget.exhausted(more, used, what))?;
        } else {
            self.budget.give(self.bytes - bytes);
        }
        self.bytes = bytes;
        Ok(())
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.budget.give(self.bytes);
    }
}

/// The memory cap a worker takes by default: three quarters of what it may
/// use, which is the smaller of the host's RAM and its control group's limit
/// (so a container answers RESOURCE_EXHAUSTED instead of being OOM-killed).
pub fn default_max_memory() -> u64 {
    let host = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| meminfo_total(&s));
    let cgroup = cgroup_limit();
    match (host, cgroup) {
        (Some(h), Some(c)) => h.min(c) / 4 * 3,
        (Some(m), None) | (None, Some(m)) => m / 4 * 3,
        (None, None) => 4 << 30,
    }
}

/// `MemTotal` of /proc/meminfo, in bytes.
fn meminfo_total(meminfo: &str) -> Option<u64> {
    meminfo
        .lines()
        .find(|l| l.starts_with("MemTotal:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<u64>().ok())
        .and_then(|kb| kb.checked_mul(1024))
        .filter(|&b| b > 0)
}

/// The memory limit of this process's control group, or None when unlimited
/// or unreadable. A limit set on an ancestor binds as well (a pod's limit sits
/// above its containers' groups), so the smallest along the path counts.
fn cgroup_limit() -> Option<u64> {
    let own = std::fs::read_to_string("/proc/self/cgroup").unwrap_or_default();
    cgroup_limit_files(&own)
        .iter()
        .filter_map(|p| std::fs::read_to_string(p).ok())
        .filter_map(|s| parse_cgroup_limit(&s))
        .min()
}

/// The limit files that may bind a process whose `/proc/self/cgroup` reads
/// `own`: v2 `memory.max` ("0::/path") and v1 `memory.limit_in_bytes` (a line
/// whose controllers include `memory`), for its group and each ancestor. In a
/// container the path may name the host's hierarchy while `/sys/fs/cgroup`
/// shows the container's own group; then only the mount's root exists.
fn cgroup_limit_files(own: &str) -> Vec<String> {
    let mut files = Vec::new();
    for line in own.lines() {
        let mut parts = line.splitn(3, ':');
        let (_, controllers, path) = (parts.next(), parts.next(), parts.next());
        let (Some(controllers), Some(path)) = (controllers, path) else {
            continue;
        };
        let (root, file) = if controllers.is_empty() {
            ("/sys/fs/cgroup", "memory.max")
        } else if controllers.split(',').any(|c| c == "memory") {
            ("/sys/fs/cgroup/memory", "memory.limit_in_bytes")
        } else {
            continue;
        };
        let mut dir = path.trim_matches('/').to_string();
        loop {
            files.push(if dir.is_empty() {
                format!("{root}/{file}")
            } else {
                format!("{root}/{dir}/{file}")
            });
            if dir.is_empty() {
                break;
            }
            dir.truncate(dir.rfind('/').unwrap_or(0));
        }
    }
    files
}

/// A cgroup limit file's value; None for `max` and for v1's "unlimited"
/// (a number near 2⁶³).
fn parse_cgroup_limit(s: &str) -> Option<u64> {
    let v: u64 = s.trim().parse().ok()?;
    (v > 0 && v < (1 << 62)).then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_never_exceed_the_cap_together() {
        let b = Budget::new(100);
        let r1 = b.reserve(60, "a").unwrap();
        let e = b.reserve(50, "second job").unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert!(e.message().contains("second job"), "{}", e.message());
        let mut r2 = b.reserve(40, "b").unwrap();
        assert_eq!(b.used(), 100);
        assert!(r2.resize(41, "grow").is_err());
        r2.resize(10, "shrink").unwrap();
        assert_eq!(b.used(), 70);
        drop(r1);
        assert_eq!(b.used(), 10);
        drop(r2);
        assert_eq!(b.used(), 0);
        assert_eq!(b.peak(), 100);
        assert!(b.reserve(u64::MAX, "huge").is_err());
    }

    #[test]
    fn concurrent_reservations_stay_within_the_cap() {
        let b = Budget::new(1000);
        let held: Vec<_> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..8)
                .map(|_| {
                    s.spawn(|| {
                        (0..100)
                            .filter_map(|_| b.reserve(7, "x").ok())
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(held.len(), 1000 / 7);
        assert!(b.peak() <= 1000);
    }

    #[test]
    fn limits_parse() {
        assert_eq!(parse_cgroup_limit("max\n"), None);
        assert_eq!(parse_cgroup_limit("9223372036854771712\n"), None);
        assert_eq!(parse_cgroup_limit("2147483648\n"), Some(2 << 30));
        assert_eq!(parse_cgroup_limit("garbage"), None);
        assert_eq!(
            meminfo_total("MemTotal:       24576000 kB\nMemFree: 1 kB\n"),
            Some(24_576_000 * 1024)
        );
        assert_eq!(meminfo_total("MemTotal: 99999999999999999999 kB"), None);
        assert!(default_max_memory() >= 1 << 20);
    }

    #[test]
    fn every_ancestor_of_the_group_is_a_candidate() {
        let v1 = cgroup_limit_files("4:memory:/pod/ctr\n3:cpu:/x\n");
        assert_eq!(
            v1,
            [
                "/sys/fs/cgroup/memory/pod/ctr/memory.limit_in_bytes",
                "/sys/fs/cgroup/memory/pod/memory.limit_in_bytes",
                "/sys/fs/cgroup/memory/memory.limit_in_bytes",
            ]
        );
        let v2 = cgroup_limit_files("0::/a/b\n");
        assert_eq!(
            v2,
            [
                "/sys/fs/cgroup/a/b/memory.max",
                "/sys/fs/cgroup/a/memory.max",
                "/sys/fs/cgroup/memory.max",
            ]
        );
        assert_eq!(cgroup_limit_files("0::/\n"), ["/sys/fs/cgroup/memory.max"]);
        assert!(cgroup_limit_files("garbage\n2:cpu,cpuacct:/\n").is_empty());
    }
}
