//! Where this process's search time goes (ARCHITECTURE §6): thread time in
//! search tasks, and for the keyed sweeps, the wall time of their parallel
//! sections, and the thread time those sections left idle before a thread's
//! first part (lag) and after its last (tail). The
//! figures are process-wide counters; a caller takes a [`Profile`] before and
//! after a search and keeps the difference.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

static BUSY: AtomicU64 = AtomicU64::new(0);
static PREP: AtomicU64 = AtomicU64::new(0);
static SWEEPS: AtomicU64 = AtomicU64::new(0);
static SWEEP_WALL: AtomicU64 = AtomicU64::new(0);
static SWEEP_LAG: AtomicU64 = AtomicU64::new(0);
static SWEEP_TAIL: AtomicU64 = AtomicU64::new(0);

fn nanos(since: Instant) -> u64 {
    u64::try_from(since.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

/// The counters at one moment, in nanoseconds; [`Profile::since`] gives
/// what happened between two.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Profile {
    /// Thread time in search tasks, all threads. Set against a search's
    /// wall time × threads, it gives how long the threads sat idle.
    pub busy: u64,
    /// Wall time before the sweeps: each query's start from its coherence
    /// candidates and its seed.
    pub prep: u64,
    /// Keyed sweeps run (one per search of a range).
    pub sweeps: u64,
    /// Wall time inside the sweeps' parallel sections.
    pub sweep_wall: u64,
    /// Thread time in the sweeps before each thread's first part (all of a
    /// sweep for a thread that got none).
    pub sweep_lag: u64,
    /// Thread time in the sweeps after each thread's last part.
    pub sweep_tail: u64,
}

impl Profile {
    /// The counters now.
    pub fn now() -> Self {
        Self {
            busy: BUSY.load(Ordering::Relaxed),
            prep: PREP.load(Ordering::Relaxed),
            sweeps: SWEEPS.load(Ordering::Relaxed),
            sweep_wall: SWEEP_WALL.load(Ordering::Relaxed),
            sweep_lag: SWEEP_LAG.load(Ordering::Relaxed),
            sweep_tail: SWEEP_TAIL.load(Ordering::Relaxed),
        }
    }

    /// What was added to the counters after `earlier`.
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            busy: self.busy.saturating_sub(earlier.busy),
            prep: self.prep.saturating_sub(earlier.prep),
            sweeps: self.sweeps.saturating_sub(earlier.sweeps),
            sweep_wall: self.sweep_wall.saturating_sub(earlier.sweep_wall),
            sweep_lag: self.sweep_lag.saturating_sub(earlier.sweep_lag),
            sweep_tail: self.sweep_tail.saturating_sub(earlier.sweep_tail),
        }
    }

    /// Adds `other`'s figures to these.
    pub fn add(&mut self, other: &Self) {
        self.busy += other.busy;
        self.prep += other.prep;
        self.sweeps += other.sweeps;
        self.sweep_wall += other.sweep_wall;
        self.sweep_lag += other.sweep_lag;
        self.sweep_tail += other.sweep_tail;
    }
}

/// Adds the time from its start to its drop to one counter.
pub(crate) struct Timer {
    into: &'static AtomicU64,
    since: Instant,
}

impl Timer {
    /// Thread time in a search task ([`Profile::busy`]).
    pub(crate) fn busy() -> Self {
        Self {
            into: &BUSY,
            since: Instant::now(),
        }
    }

    /// Wall time before a sweep ([`Profile::prep`]).
    pub(crate) fn prep() -> Self {
        Self {
            into: &PREP,
            since: Instant::now(),
        }
    }
}

impl Drop for Timer {
    fn drop(&mut self) {
        self.into.fetch_add(nanos(self.since), Ordering::Relaxed);
    }
}

/// One sweep's parallel section on `threads` threads: each task calls
/// [`SweepTimer::joined`] as it takes its first part and [`SweepTimer::done`]
/// when it finds none left. The section's thread time (threads × wall) is
/// then busy time, lag (before a thread's first part, or the whole section
/// for a thread that got none) and tail (after a thread's last part).
pub(crate) struct SweepTimer {
    entry: Instant,
    threads: u64,
    joined: AtomicU64,
    started: AtomicU64,
    finished: AtomicU64,
}

impl SweepTimer {
    pub(crate) fn enter(threads: usize) -> Self {
        Self {
            entry: Instant::now(),
            threads: threads as u64,
            joined: AtomicU64::new(0),
            started: AtomicU64::new(0),
            finished: AtomicU64::new(0),
        }
    }

    pub(crate) fn joined(&self) {
        self.joined.fetch_add(1, Ordering::Relaxed);
        self.started.fetch_add(nanos(self.entry), Ordering::Relaxed);
    }

    pub(crate) fn done(&self) {
        self.finished
            .fetch_add(nanos(self.entry), Ordering::Relaxed);
    }
}

impl Drop for SweepTimer {
    fn drop(&mut self) {
        let wall = nanos(self.entry);
        let joined = self.joined.load(Ordering::Relaxed).min(self.threads);
        let lag = self.started.load(Ordering::Relaxed) + (self.threads - joined) * wall;
        let tail = (joined * wall).saturating_sub(self.finished.load(Ordering::Relaxed));
        SWEEPS.fetch_add(1, Ordering::Relaxed);
        SWEEP_WALL.fetch_add(wall, Ordering::Relaxed);
        SWEEP_LAG.fetch_add(lag, Ordering::Relaxed);
        SWEEP_TAIL.fetch_add(tail, Ordering::Relaxed);
    }
}
