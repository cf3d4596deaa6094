//! The reference positions of a level in global-index order (ARCHITECTURE §3.3),
//! held as runs of consecutive pixels on a row: a few bytes per row of the
//! sample instead of eight per pixel, so an 8192² level's positions take
//! kilobytes, not half a gigabyte.

use std::ops::Range;

/// One run: `len` positions (x..x + len, y) with global indices from `first`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Run {
    first: u64,
    x: u32,
    y: u32,
    len: u32,
}

/// Reference positions in scan-line order; index `i` is the `i`-th position.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Positions {
    runs: Vec<Run>,
    len: u64,
}

impl Positions {
    /// An empty set.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends position (x, y); positions must come in scan-line order.
    ///
    /// # Panics
    /// If (x, y) does not come after the last position in scan-line order.
    pub fn push(&mut self, x: u32, y: u32) {
        if let Some(last) = self.runs.last_mut() {
            let end = u64::from(last.x) + u64::from(last.len);
            assert!(
                (y, u64::from(x)) >= (last.y, end),
                "positions out of scan-line order: ({x}, {y}) after ({}, {})",
                end - 1,
                last.y
            );
            if last.y == y && end == u64::from(x) && last.len < u32::MAX {
                last.len += 1;
                self.len += 1;
                return;
            }
        }
        self.runs.push(Run {
            first: self.len,
            x,
            y,
            len: 1,
        });
        self.len += 1;
    }

    /// Positions from a list in scan-line order.
    pub fn from_list(list: &[[u32; 2]]) -> Self {
        let mut out = Self::new();
        for p in list {
            out.push(p[0], p[1]);
        }
        out.runs.shrink_to_fit();
        out
    }

    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The position of global index `index`.
    pub fn get(&self, index: u64) -> Option<[u32; 2]> {
        if index >= self.len {
            return None;
        }
        let r = &self.runs[self.runs.partition_point(|r| r.first <= index) - 1];
        Some([r.x + (index - r.first) as u32, r.y])
    }

    /// The global index of position (x, y), if it is a reference position.
    pub fn index_of(&self, x: u32, y: u32) -> Option<u64> {
        let k = self.runs.partition_point(|r| (r.y, r.x) <= (y, x));
        let r = self.runs.get(k.checked_sub(1)?)?;
        (r.y == y && x - r.x < r.len).then(|| r.first + u64::from(x - r.x))
    }

    /// The runs that cover global indices `range`, clipped to it: (first index,
    /// x, y, length) with the positions (x..x + length, y).
    pub fn runs(&self, range: Range<u64>) -> impl Iterator<Item = (u64, u32, u32, u32)> + '_ {
        let end = range.end.min(self.len);
        let start = range.start.min(end);
        let k = self
            .runs
            .partition_point(|r| r.first + u64::from(r.len) <= start);
        self.runs[k..]
            .iter()
            .take_while(move |r| r.first < end)
            .map(move |r| {
                let a = r.first.max(start);
                let b = (r.first + u64::from(r.len)).min(end);
                (a, r.x + (a - r.first) as u32, r.y, (b - a) as u32)
            })
    }

    /// Every position in index order.
    pub fn iter(&self) -> impl Iterator<Item = [u32; 2]> + '_ {
        self.iter_range(0..self.len)
    }

    /// The positions of global indices `range`, in index order.
    pub fn iter_range(&self, range: Range<u64>) -> impl Iterator<Item = [u32; 2]> + '_ {
        self.runs(range)
            .flat_map(|(_, x, y, len)| (x..x + len).map(move |x| [x, y]))
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        (self.runs.capacity() * std::mem::size_of::<Run>()) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn list() -> impl Strategy<Value = Vec<[u32; 2]>> {
        proptest::collection::btree_set((0u32..40, 0u32..12), 0..200)
            .prop_map(|s| s.into_iter().map(|(y, x)| [x, y]).collect())
    }

    proptest! {
        #[test]
        fn runs_hold_the_list(l in list(), a in 0u64..220, b in 0u64..220) {
            let p = Positions::from_list(&l);
            prop_assert_eq!(p.len(), l.len());
            prop_assert_eq!(p.iter().collect::<Vec<_>>(), l.clone());
            for (i, q) in l.iter().enumerate() {
                prop_assert_eq!(p.get(i as u64), Some(*q));
                prop_assert_eq!(p.index_of(q[0], q[1]), Some(i as u64));
            }
            prop_assert_eq!(p.get(l.len() as u64), None);
            for y in 0..13 {
                for x in 0..41 {
                    let want = l.iter().position(|q| *q == [x, y]).map(|i| i as u64);
                    prop_assert_eq!(p.index_of(x, y), want);
                }
            }
            let (a, b) = (a.min(b), a.max(b));
            let want: Vec<_> = l.iter().copied().skip(a as usize).take(b.saturating_sub(a) as usize).collect();
            prop_assert_eq!(p.iter_range(a..b).collect::<Vec<_>>(), want);
            let mut next = a.min(l.len() as u64);
            for (first, _, _, len) in p.runs(a..b) {
                prop_assert_eq!(first, next);
                next += u64::from(len);
            }
        }
    }

    #[test]
    #[should_panic(expected = "scan-line order")]
    fn out_of_order_is_refused() {
        let mut p = Positions::new();
        p.push(3, 1);
        p.push(2, 1);
    }
}
