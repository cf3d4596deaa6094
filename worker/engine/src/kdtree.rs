//! An exact k-d tree over the vectors of a low-dimensional space
//! (ARCHITECTURE §3.5): the index behind top-k searches of spaces whose
//! vectors have at most [`MAX_DIMS`] components, such as the appearance
//! vectors of the k-coherence sets (Manke–Wünsche §3). Scanning every vector
//! for every query costs `n²` on an all-pairs search; the tree visits only the
//! cells whose lower bound can still beat a query's k-th best, so the answer
//! is the scan's, bit for bit: the same integer distances, the same
//! (distance, index) order, the same `worst` cut.
//!
//! Each inner node splits its vectors at the median of its widest component
//! (left: values ≤ the split, right: values ≥ it), and keeps its vectors'
//! bounding box. A node's lower bound is the distance from the query to that
//! box: tighter than the distance to the cell its splits bound (the bound
//! Arya and Mount keep incrementally), since in 9 dimensions most of a cell
//! is empty. Children are visited nearer box first.

use rayon::prelude::*;

use crate::kernel::{Kernel, Params};
use crate::layout::{Layout, Metric};
use crate::merge::Hit;

/// Most components a space may have for the tree to serve it; above this a
/// k-d tree prunes little and the kernels' scan is faster.
pub const MAX_DIMS: usize = 16;
/// Vectors per leaf at most.
const LEAF: usize = 12;
/// Vectors below which no tree is built (the scan is as fast).
pub const MIN_VECTORS: usize = 512;

/// One node: a leaf (`left == NONE`) holding `points[lo..hi]`, or a split.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: u32,
    hi: u32,
    dim: u8,
    split: u8,
    left: u32,
    right: u32,
}

const NONE: u32 = u32::MAX;

/// The tree: the unpadded vectors in tree order, their global indices and
/// the nodes (the root is node 0).
#[derive(Debug, Clone)]
pub(crate) struct KdTree {
    /// Whether component `d` belongs to the hi part (else the lo part).
    hi_part: Vec<bool>,
    /// Padded offset of component `d` in a query.
    offset: Vec<usize>,
    /// The vectors in tree order, each zero-padded to [`MAX_DIMS`] bytes, so
    /// a leaf's distances are whole-register operations.
    points: Vec<[u8; MAX_DIMS]>,
    index: Vec<u64>,
    /// The global indices the tree holds.
    span: std::ops::Range<u64>,
    nodes: Vec<Node>,
    /// Per node, the least and the greatest value of each component over its
    /// vectors (padded like the points): the node's bounding box.
    boxes: Vec<[[u8; MAX_DIMS]; 2]>,
}

impl KdTree {
    /// Whether a tree can serve searches of this layout.
    pub(crate) fn applies(layout: &Layout) -> bool {
        (1..=MAX_DIMS).contains(&layout.dims())
    }

    /// Builds the tree of `count` vectors given unpadded (`layout.dims()`
    /// bytes each) with global indices `start..start + count`.
    pub(crate) fn build(layout: &Layout, start: u64, raw: Vec<u8>, count: usize) -> Self {
        let dims = layout.dims();
        debug_assert_eq!(raw.len(), dims * count);
        let offset: Vec<usize> = (0..layout.hi_len)
            .chain(layout.hi_pad..layout.hi_pad + layout.lo_len)
            .collect();
        let hi_part = (0..dims).map(|d| d < layout.hi_len).collect();
        let mut order: Vec<u32> = (0..count as u32).collect();
        let mut nodes = Vec::with_capacity(2 * count / LEAF + 1);
        let mut boxes = Vec::with_capacity(2 * count / LEAF + 1);
        split(&raw, dims, &mut order, 0, &mut nodes, &mut boxes);
        let points = order
            .iter()
            .map(|&i| {
                let i = i as usize;
                let mut p = [0u8; MAX_DIMS];
                p[..dims].copy_from_slice(&raw[i * dims..(i + 1) * dims]);
                p
            })
            .collect();
        let index = order.iter().map(|&i| start + u64::from(i)).collect();
        Self {
            hi_part,
            offset,
            points,
            index,
            span: start..start + count as u64,
            nodes,
            boxes,
        }
    }

    /// Bytes held.
    pub(crate) fn bytes(&self) -> u64 {
        (self.points.len() * MAX_DIMS
            + self.index.len() * 8
            + self.nodes.len() * (size_of::<Node>() + 2 * MAX_DIMS)) as u64
    }

    /// The `k` best vectors with an index in `range` and a distance below
    /// `worst[q]`, per query (padded values; full masks), sorted by
    /// (distance, index): what the scan answers.
    pub(crate) fn search_topk(
        &self,
        queries: &[&[u8]],
        params: &Params,
        range: std::ops::Range<u64>,
        k: usize,
        worst: &[u64],
        kernel: Kernel,
    ) -> Vec<Vec<Hit>> {
        let weight: Vec<u64> = self
            .hi_part
            .iter()
            .map(|&hi| {
                u64::from(if hi {
                    params.weights.hi
                } else {
                    params.weights.lo
                })
            })
            .collect();
        // One weight for every component (a one-part space): a distance is
        // that weight times the plain sum over the padded vector.
        let uniform = weight
            .first()
            .copied()
            .filter(|w| weight.iter().all(|x| x == w));
        #[cfg(target_arch = "x86_64")]
        {
            if matches!(kernel, Kernel::Avx2 | Kernel::Avx512) {
                assert!(
                    crate::kernel::x86::has_avx2(),
                    "AVX2 tree search on a CPU without AVX2"
                );
            }
            if kernel == Kernel::Avx512 {
                assert!(
                    crate::kernel::x86::has_avx512(),
                    "AVX-512 tree search on a CPU without AVX-512"
                );
            }
        }
        // Every vector of the tree in range: no per-vector range test.
        let whole = range.start <= self.span.start && self.span.end <= range.end;
        queries
            .par_iter()
            .zip(worst)
            .map(|(q, &worst)| {
                if worst == 0 {
                    // Nothing is below a cut of 0.
                    return Vec::new();
                }
                let mut q16 = [0u8; MAX_DIMS];
                for (slot, &o) in q16.iter_mut().zip(&self.offset) {
                    *slot = q[o];
                }
                let mut s = Search {
                    tree: self,
                    whole,
                    q: &q16,
                    weight: &weight,
                    uniform: uniform.unwrap_or(0),
                    range: range.clone(),
                    k,
                    limit: worst.saturating_sub(1),
                    list: Vec::with_capacity(k + 1),
                    stack: Vec::with_capacity(64),
                };
                match (params.metric, uniform.is_some()) {
                    (Metric::L1, true) => s.run::<L1, true>(kernel),
                    (Metric::L1, false) => s.run::<L1, false>(kernel),
                    (Metric::L2, true) => s.run::<L2, true>(kernel),
                    (Metric::L2, false) => s.run::<L2, false>(kernel),
                }
                s.list
            })
            .collect()
    }
}

/// Splits `order` (indices into `raw`) into the subtree rooted at a new node
/// and returns that node's number.
fn split(
    raw: &[u8],
    dims: usize,
    order: &mut [u32],
    lo: usize,
    nodes: &mut Vec<Node>,
    boxes: &mut Vec<[[u8; MAX_DIMS]; 2]>,
) -> u32 {
    let me = nodes.len() as u32;
    let hi = lo + order.len();
    nodes.push(Node {
        lo: lo as u32,
        hi: hi as u32,
        dim: 0,
        split: 0,
        left: NONE,
        right: NONE,
    });
    // The bounding box, and the widest component.
    let mut bx = [[0u8; MAX_DIMS]; 2];
    let mut best = (0u8, 0usize);
    for d in 0..dims {
        let (mut a, mut b) = (u8::MAX, 0u8);
        for &i in order.iter() {
            let v = raw[i as usize * dims + d];
            a = a.min(v);
            b = b.max(v);
        }
        (bx[0][d], bx[1][d]) = (a, b);
        let spread = b.saturating_sub(a);
        if spread > best.0 {
            best = (spread, d);
        }
    }
    boxes.push(bx);
    if order.len() <= LEAF {
        return me;
    }
    if best.0 == 0 {
        // Every vector here is the same: one leaf, however many.
        return me;
    }
    let d = best.1;
    let mid = order.len() / 2;
    order.select_nth_unstable_by_key(mid, |&i| (raw[i as usize * dims + d], i));
    let value = raw[order[mid] as usize * dims + d];
    let (left, right) = order.split_at_mut(mid);
    let l = split(raw, dims, left, lo, nodes, boxes);
    let r = split(raw, dims, right, lo + mid, nodes, boxes);
    let n = &mut nodes[me as usize];
    n.dim = d as u8;
    n.split = value;
    n.left = l;
    n.right = r;
    me
}

/// The metric as a type-level switch of [`Search`]: `L2` squares the
/// gaps, `L1` sums them.
const L1: bool = false;
const L2: bool = true;

/// One query's search.
struct Search<'a> {
    tree: &'a KdTree,
    /// Whether every vector of the tree lies in `range`.
    whole: bool,
    /// The query's components, zero-padded like the points.
    q: &'a [u8; MAX_DIMS],
    weight: &'a [u64],
    /// The weight of every component, when they all have the same (the
    /// `UNIFORM` searches; else unused).
    uniform: u64,
    range: std::ops::Range<u64>,
    k: usize,
    /// Largest distance a vector may have and still enter the list: the
    /// k-th best's once the list is full, else one below the query's
    /// `worst` (equal to the limit may still win on a lower index).
    limit: u64,
    /// The best so far, sorted by (distance, index).
    list: Vec<Hit>,
    /// Farther children still to visit, with their bounds.
    stack: Vec<(u32, u64)>,
}

impl Search<'_> {
    /// The search, compiled for the engine's kernel's instruction set
    /// (AVX2 or AVX-512, which the caller checked the CPU for): the box
    /// bounds and leaf distances of 16 bytes become whole-register
    /// operations, and the answers do not depend on it.
    #[inline(always)]
    fn run<const SQUARED: bool, const UNIFORM: bool>(&mut self, kernel: Kernel) {
        match kernel {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU has AVX2 (asserted by the caller); the
            // traversal is safe code compiled for it.
            Kernel::Avx2 => unsafe { self.descend_avx2::<SQUARED, UNIFORM>() },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: the CPU has AVX-512 (asserted by the caller).
            Kernel::Avx512 => unsafe { self.descend_avx512::<SQUARED, UNIFORM>() },
            _ => self.descend::<SQUARED, UNIFORM>(),
        }
    }

    /// [`Search::descend`] compiled for AVX2.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn descend_avx2<const SQUARED: bool, const UNIFORM: bool>(&mut self) {
        self.descend::<SQUARED, UNIFORM>();
    }

    /// [`Search::descend`] compiled for AVX-512.
    ///
    /// # Safety
    /// The CPU must have AVX-512 (F, BW, VL).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl")]
    unsafe fn descend_avx512<const SQUARED: bool, const UNIFORM: bool>(&mut self) {
        self.descend::<SQUARED, UNIFORM>();
    }

    /// The search from the root: depth first, down the nearer box's child
    /// at each split with the farther one stacked, a node visited only
    /// while its box may still hold a vector within the limit (the limit
    /// tightens as the list fills, so a stacked child is tested again when
    /// its turn comes).
    #[inline(always)]
    fn descend<const SQUARED: bool, const UNIFORM: bool>(&mut self) {
        if self.box_bound::<SQUARED, UNIFORM>(0) > self.limit {
            return;
        }
        let mut next = Some(0u32);
        while let Some(mut n) = next.take().or_else(|| self.pop()) {
            loop {
                let node = self.tree.nodes[n as usize];
                if node.left == NONE {
                    self.leaf::<SQUARED, UNIFORM>(node.lo as usize..node.hi as usize);
                    break;
                }
                let a = self.box_bound::<SQUARED, UNIFORM>(node.left);
                let b = self.box_bound::<SQUARED, UNIFORM>(node.right);
                let ((near, dn), (far, df)) = if a <= b {
                    ((node.left, a), (node.right, b))
                } else {
                    ((node.right, b), (node.left, a))
                };
                if dn > self.limit {
                    break;
                }
                if df <= self.limit {
                    self.stack.push((far, df));
                }
                n = near;
            }
        }
    }

    /// The next stacked node whose bound is still within the limit.
    #[inline(always)]
    fn pop(&mut self) -> Option<u32> {
        while let Some((n, bound)) = self.stack.pop() {
            if bound <= self.limit {
                return Some(n);
            }
        }
        None
    }

    /// `Σ g` (L1) or `Σ g²` (L2) over the padded component gaps `g`,
    /// weighted per component or by the one weight (the padding is zero in
    /// both the query and the tree, so it adds nothing).
    #[inline(always)]
    fn weighted<const SQUARED: bool, const UNIFORM: bool>(&self, g: &[u8; MAX_DIMS]) -> u64 {
        if UNIFORM {
            let mut sum = 0u32;
            for &x in g {
                let x = u32::from(x);
                sum += if SQUARED { x * x } else { x };
            }
            self.uniform * u64::from(sum)
        } else {
            let mut sum = 0u64;
            for (&w, &x) in self.weight.iter().zip(g) {
                let x = u64::from(x);
                sum += w * if SQUARED { x * x } else { x };
            }
            sum
        }
    }

    /// The least distance from the query to any vector of node `n`: the
    /// distance to its bounding box, tighter than the distance to the cell
    /// its splits bound (Arya and Mount's incremental bound), since the box
    /// lies inside the cell.
    #[inline(always)]
    fn box_bound<const SQUARED: bool, const UNIFORM: bool>(&self, n: u32) -> u64 {
        let [lo, hi] = &self.tree.boxes[n as usize];
        let mut gap = [0u8; MAX_DIMS];
        for d in 0..MAX_DIMS {
            gap[d] = lo[d].saturating_sub(self.q[d]) | self.q[d].saturating_sub(hi[d]);
        }
        self.weighted::<SQUARED, UNIFORM>(&gap)
    }

    #[inline(always)]
    fn leaf<const SQUARED: bool, const UNIFORM: bool>(&mut self, span: std::ops::Range<usize>) {
        for p in span {
            if !self.whole && !self.range.contains(&self.tree.index[p]) {
                continue;
            }
            let v = &self.tree.points[p];
            let mut gap = [0u8; MAX_DIMS];
            for d in 0..MAX_DIMS {
                gap[d] = v[d].abs_diff(self.q[d]);
            }
            let dist = self.weighted::<SQUARED, UNIFORM>(&gap);
            if dist > self.limit {
                continue;
            }
            let hit = Hit {
                index: self.tree.index[p],
                dist,
            };
            if self.list.len() == self.k {
                if hit.key() >= self.list[self.k - 1].key() {
                    continue;
                }
                self.list.pop();
            }
            let at = self.list.partition_point(|h| h.key() < hit.key());
            self.list.insert(at, hit);
            if self.list.len() == self.k {
                self.limit = self.list[self.k - 1].dist;
            }
        }
    }
}
