//! The block list L{B_u} of Stahlhut §4 as a bucket queue (ARCHITECTURE §3.4).
//!
//! Blocks with undefined pixels are keyed by the number of undefined pixels in
//! their neighbourhood ("hash table with p_undef as key"); ties go to the lower
//! scan-line block index. A block's key is changed in place when a copy near it
//! defines pixels in its neighbourhood (the paper's spatial lookup table is the
//! block grid itself: neighbours are found by index arithmetic).

use std::collections::BTreeSet;

/// Bucket queue over block indices with small integer keys.
#[derive(Debug, Clone)]
pub struct BlockQueue {
    buckets: Vec<BTreeSet<u32>>,
    key: Vec<u32>,
    len: usize,
    /// Lowest possibly non-empty bucket.
    low: usize,
}

const ABSENT: u32 = u32::MAX;

impl BlockQueue {
    /// A queue for `blocks` blocks with keys in `0..=max_key`.
    pub fn new(blocks: usize, max_key: u32) -> Self {
        Self {
            buckets: vec![BTreeSet::new(); max_key as usize + 1],
            key: vec![ABSENT; blocks],
            len: 0,
            low: 0,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn contains(&self, block: u32) -> bool {
        self.key[block as usize] != ABSENT
    }

    /// The key of `block`, if queued.
    pub fn key(&self, block: u32) -> Option<u32> {
        let k = self.key[block as usize];
        (k != ABSENT).then_some(k)
    }

    /// Inserts `block` with `key`, or moves it to `key` if queued.
    pub fn set(&mut self, block: u32, key: u32) {
        let key = key.min(self.buckets.len() as u32 - 1);
        let old = self.key[block as usize];
        if old == key {
            return;
        }
        if old != ABSENT {
            self.buckets[old as usize].remove(&block);
        } else {
            self.len += 1;
        }
        self.buckets[key as usize].insert(block);
        self.key[block as usize] = key;
        self.low = self.low.min(key as usize);
    }

    /// Removes `block` if queued.
    pub fn remove(&mut self, block: u32) {
        let old = self.key[block as usize];
        if old != ABSENT {
            self.buckets[old as usize].remove(&block);
            self.key[block as usize] = ABSENT;
            self.len -= 1;
        }
    }

    /// Blocks in priority order (key, then index), lazily.
    pub fn iter(&mut self) -> impl Iterator<Item = u32> + '_ {
        while self.low < self.buckets.len() && self.buckets[self.low].is_empty() {
            self.low += 1;
        }
        let low = self.low.min(self.buckets.len());
        self.buckets[low..].iter().flat_map(|b| b.iter().copied())
    }

    /// Removes and returns the head.
    pub fn pop(&mut self) -> Option<u32> {
        let head = self.iter().next()?;
        self.remove(head);
        Some(head)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn pops_in_key_then_index_order(ops in proptest::collection::vec((0u32..200, 0u32..30, proptest::bool::ANY), 1..400)) {
            let mut q = BlockQueue::new(200, 29);
            let mut model = std::collections::BTreeMap::new();
            for (b, k, del) in ops {
                if del {
                    q.remove(b);
                    model.remove(&b);
                } else {
                    q.set(b, k);
                    model.insert(b, k);
                }
                prop_assert_eq!(q.len(), model.len());
            }
            let mut expect: Vec<(u32, u32)> = model.iter().map(|(&b, &k)| (k, b)).collect();
            expect.sort();
            let got: Vec<u32> = std::iter::from_fn(|| q.pop()).collect();
            prop_assert_eq!(got, expect.iter().map(|&(_, b)| b).collect::<Vec<_>>());
        }
    }
}
