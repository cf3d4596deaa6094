//! A batch of masked query vectors in the padded layout (ARCHITECTURE §3.2,
//! §3.4): what a search compares against the reference vectors.

use crate::error::{EngineError, Result};
use crate::layout::Layout;
use crate::merge::Hit;

/// A batch of query vectors, each with its own mask of defined components
/// (ARCHITECTURE §3.4: only masked-in components are compared).
#[derive(Debug, Clone)]
pub struct QueryBatch {
    layout: Layout,
    len: usize,
    /// Padded values with masked-out components zeroed.
    values: Vec<u8>,
    /// Padded masks, 0xFF = compare, 0 = ignore (padding is 0).
    masks: Vec<u8>,
    /// Per query an answer already known to be valid (its index and exact
    /// distance), or [`Hit::NONE`]: a search only looks for better ones and may
    /// prune against it (ARCHITECTURE §3.5). Travels to the workers.
    bounds: Vec<Hit>,
    /// Per query the global indices worth trying first (coherence candidates);
    /// the engine scores those inside its range before the scan to start from
    /// a tight bound. Hints only: they never change the answer.
    candidates: Vec<Vec<u64>>,
}

impl QueryBatch {
    pub fn new(layout: Layout) -> Self {
        Self {
            layout,
            len: 0,
            values: Vec::new(),
            masks: Vec::new(),
            bounds: Vec::new(),
            candidates: Vec::new(),
        }
    }

    /// Adds a query from unpadded values and mask (`layout.dims()` bytes each,
    /// mask non-zero = defined).
    pub fn push(&mut self, values: &[u8], mask: &[u8]) -> Result<()> {
        let dims = self.layout.dims();
        if values.len() != dims {
            return Err(EngineError::Length {
                what: "query values",
                got: values.len(),
                expected: dims,
            });
        }
        if mask.len() != dims {
            return Err(EngineError::Length {
                what: "query mask",
                got: mask.len(),
                expected: dims,
            });
        }
        let s = self.layout.stride();
        let at = self.values.len();
        self.values.resize(at + s, 0);
        self.masks.resize(at + s, 0);
        let m: Vec<u8> = mask
            .iter()
            .map(|&b| if b != 0 { 0xFF } else { 0 })
            .collect();
        let v: Vec<u8> = values.iter().zip(&m).map(|(&v, &m)| v & m).collect();
        self.layout.scatter(&v, &mut self.values[at..at + s]);
        self.layout.scatter(&m, &mut self.masks[at..at + s]);
        self.len += 1;
        self.bounds.push(Hit::NONE);
        self.candidates.push(Vec::new());
        Ok(())
    }

    /// Sets the known answer of query `q` (an index with its exact distance, or
    /// [`Hit::NONE`]). A wrong distance makes the search wrong: callers compute
    /// it with [`crate::distance`] from the level's own data.
    pub fn set_bound(&mut self, q: usize, hit: Hit) {
        self.bounds[q] = hit;
    }

    /// The known answer of query `q` ([`Hit::NONE`] if none).
    pub fn bound(&self, q: usize) -> Hit {
        self.bounds[q]
    }

    /// Every query's known answer.
    pub fn bounds(&self) -> &[Hit] {
        &self.bounds
    }

    /// Sets the coherence candidates of query `q` (global indices, tried first).
    pub fn set_candidates(&mut self, q: usize, candidates: Vec<u64>) {
        self.candidates[q] = candidates;
    }

    /// The coherence candidates of query `q`.
    pub fn candidates(&self, q: usize) -> &[u64] {
        &self.candidates[q]
    }

    /// The same queries without bounds or candidates: an unpruned search.
    pub fn without_hints(&self) -> QueryBatch {
        QueryBatch {
            bounds: vec![Hit::NONE; self.len],
            candidates: vec![Vec::new(); self.len],
            ..self.clone()
        }
    }

    /// Adds a query with every component defined.
    pub fn push_full(&mut self, values: &[u8]) -> Result<()> {
        let mask = vec![0xFFu8; values.len()];
        self.push(values, &mask)
    }

    pub fn layout(&self) -> Layout {
        self.layout
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Padded (masked) values of query `q`.
    pub fn values(&self, q: usize) -> &[u8] {
        let s = self.layout.stride();
        &self.values[q * s..(q + 1) * s]
    }

    /// Padded mask of query `q`.
    pub fn mask(&self, q: usize) -> &[u8] {
        let s = self.layout.stride();
        &self.masks[q * s..(q + 1) * s]
    }

    /// The unpadded values and masks of every query, concatenated (what
    /// [`QueryBatch::push`] took): the form queries travel in on the wire.
    pub fn unpadded(&self) -> (Vec<u8>, Vec<u8>) {
        self.unpadded_range(0..self.len)
    }

    /// [`QueryBatch::unpadded`] of the queries `qs` only.
    pub fn unpadded_range(&self, qs: std::ops::Range<usize>) -> (Vec<u8>, Vec<u8>) {
        let n = qs.len() * self.layout.dims();
        let (mut values, mut masks) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for q in qs {
            self.layout.unpad_into(self.values(q), &mut values);
            self.layout.unpad_into(self.mask(q), &mut masks);
        }
        (values, masks)
    }

    /// The queries `qs` of this batch, in that order, without bounds or
    /// candidates (used by LBG to search per-query partitions).
    pub(crate) fn select(&self, qs: impl IntoIterator<Item = usize>) -> QueryBatch {
        let s = self.layout.stride();
        let mut out = QueryBatch::new(self.layout);
        for q in qs {
            out.values
                .extend_from_slice(&self.values[q * s..(q + 1) * s]);
            out.masks.extend_from_slice(&self.masks[q * s..(q + 1) * s]);
            out.len += 1;
            out.bounds.push(Hit::NONE);
            out.candidates.push(Vec::new());
        }
        out
    }

    /// `count` padded vectors (`count × stride` bytes, padding zero) as queries
    /// with every component defined (LBG scores vectors against seeds this way).
    pub(crate) fn full_from_padded(layout: Layout, padded: &[u8], count: usize) -> QueryBatch {
        let s = layout.stride();
        let mut full = vec![0u8; s];
        layout.scatter(&vec![0xFFu8; layout.dims()], &mut full);
        let mut masks = Vec::with_capacity(count * s);
        let mut values = Vec::with_capacity(count * s);
        for v in padded[..count * s].chunks_exact(s) {
            masks.extend_from_slice(&full);
            values.extend(v.iter().zip(&full).map(|(&x, &m)| x & m));
        }
        QueryBatch {
            layout,
            len: count,
            values,
            masks,
            bounds: vec![Hit::NONE; count],
            candidates: vec![Vec::new(); count],
        }
    }

    pub(crate) fn all_values(&self) -> &[u8] {
        &self.values
    }

    pub(crate) fn all_masks(&self) -> &[u8] {
        &self.masks
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Geometry;

    #[test]
    fn unpadded_round_trips_through_a_batch() {
        let l = Geometry::new(5, 3).unwrap().layout();
        let dims = l.dims();
        let v: Vec<u8> = (0..dims).map(|i| i as u8 + 1).collect();
        let m: Vec<u8> = (0..dims).map(|i| u8::from(i % 3 != 0)).collect();
        let mut b = QueryBatch::new(l);
        b.push(&v, &m).unwrap();
        b.push_full(&v).unwrap();
        let (values, masks) = b.unpadded();
        assert_eq!(values.len(), 2 * dims);
        let mut again = QueryBatch::new(l);
        for q in 0..2 {
            again
                .push(
                    &values[q * dims..(q + 1) * dims],
                    &masks[q * dims..(q + 1) * dims],
                )
                .unwrap();
        }
        for q in 0..2 {
            assert_eq!(again.values(q), b.values(q));
            assert_eq!(again.mask(q), b.mask(q));
        }
        let (one_v, one_m) = b.unpadded_range(1..2);
        assert_eq!(one_v, values[dims..]);
        assert_eq!(one_m, masks[dims..]);
    }
}
