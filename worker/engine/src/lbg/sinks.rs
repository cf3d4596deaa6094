//! Kernel sinks of LBG (Stahlhut §8, ARCHITECTURE §3.8): nearest and second-nearest
//! seed per vector while training, the nearest seeds per query and the best hit
//! per query inside a partition. Ties go to the lowest seed or global index.

use crate::kernel::Sink;
use crate::merge::Hit;

/// Nearest and second-nearest seed of every vector of a chunk. The seeds are
/// the queries; per vector they arrive in ascending seed order, so a strict `<`
/// keeps the lowest seed index among ties.
pub(super) struct AssignSink {
    pub(super) best: Vec<u64>,
    pub(super) arg: Vec<u32>,
    pub(super) second: Vec<u64>,
    /// Index of the first seed of the block being scanned.
    pub(super) base: u32,
}

impl AssignSink {
    pub(super) fn new(n: usize) -> Self {
        Self {
            best: vec![u64::MAX; n],
            arg: vec![0; n],
            second: vec![u64::MAX; n],
            base: 0,
        }
    }

    #[inline(always)]
    fn offer(&mut self, i: usize, seed: u32, x: u64) {
        if x < self.best[i] {
            self.second[i] = self.best[i];
            self.best[i] = x;
            self.arg[i] = seed;
        } else if x < self.second[i] {
            self.second[i] = x;
        }
    }
}

impl Sink for AssignSink {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        let i = index as usize;
        let (mut b, mut a, mut s) = (self.best[i], self.arg[i], self.second[i]);
        for (j, &x) in d.iter().enumerate() {
            if x < b {
                s = b;
                b = x;
                a = self.base + j as u32;
            } else if x < s {
                s = x;
            }
        }
        self.best[i] = b;
        self.arg[i] = a;
        self.second[i] = s;
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        for (t, &x) in d.iter().enumerate() {
            self.offer(first as usize + t, self.base + q as u32, x);
        }
    }
}

/// The `p` nearest seeds of every query, sorted by (distance, seed index).
/// Seed rows at or beyond `k` are padding and ignored.
pub(super) struct TopSeedSink {
    p: usize,
    k: usize,
    pub(super) lists: Vec<Vec<(u64, u32)>>,
    worst: Vec<u64>,
}

impl TopSeedSink {
    pub(super) fn new(nq: usize, p: usize, k: usize) -> Self {
        Self {
            p,
            k,
            lists: vec![Vec::with_capacity(p + 1); nq],
            worst: vec![u64::MAX; nq],
        }
    }

    #[inline(always)]
    fn offer(&mut self, q: usize, seed: usize, x: u64) {
        if x >= self.worst[q] || seed >= self.k {
            return;
        }
        let list = &mut self.lists[q];
        let pos = list.partition_point(|e| e.0 <= x);
        list.insert(pos, (x, seed as u32));
        if list.len() > self.p {
            list.pop();
        }
        if list.len() == self.p {
            self.worst[q] = list[self.p - 1].0;
        }
    }
}

impl Sink for TopSeedSink {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        for (q, &x) in d.iter().enumerate() {
            self.offer(q, index as usize, x);
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        for (t, &x) in d.iter().enumerate() {
            self.offer(q, first as usize + t, x);
        }
    }
}

/// Best (distance, global index) of each query over partition rows; rows are
/// in ascending global order inside a partition, padding rows are skipped.
pub(super) struct PartSink<'a> {
    pub(super) row_index: &'a [u64],
    pub(super) best: Vec<Hit>,
}

impl Sink for PartSink<'_> {
    #[inline(always)]
    fn row(&mut self, index: u64, d: &[u64]) {
        let g = self.row_index[index as usize];
        if g == u64::MAX {
            return;
        }
        for (b, &x) in self.best.iter_mut().zip(d) {
            if x < b.dist {
                *b = Hit { index: g, dist: x };
            }
        }
    }

    #[inline(always)]
    fn run(&mut self, q: usize, first: u64, d: &[u64]) {
        let mut b = self.best[q];
        for (t, &x) in d.iter().enumerate() {
            if x < b.dist {
                let g = self.row_index[first as usize + t];
                if g != u64::MAX {
                    b = Hit { index: g, dist: x };
                }
            }
        }
        self.best[q] = b;
    }
}
