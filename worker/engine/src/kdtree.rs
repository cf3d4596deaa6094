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
    dims: usize,
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
            dims,
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
        if matches!(kernel, Kernel::Avx2 | Kernel::Avx512) {
            assert!(
                crate::kernel::x86::has_avx2(),
                "AVX2 tree search on a CPU without AVX2"
            );
        }
        // Every vector of the tree in range: no per-vector range test.
        let whole = range.start <= self.span.start && self.span.end <= range.end;
        queries
            .par_iter()
            .zip(worst)
            .map(|(q, &worst)| {
                let mut q16 = [0u8; MAX_DIMS];
                for (slot, &o) in q16.iter_mut().zip(&self.offset) {
                    *slot = q[o];
                }
                let mut s = Search {
                    tree: self,
                    whole,
                    q: &q16,
                    weight: &weight,
                    uniform,
                    metric: params.metric,
                    range: range.clone(),
                    k,
                    worst,
                    list: Vec::with_capacity(k + 1),
                };
                match kernel {
                    #[cfg(target_arch = "x86_64")]
                    Kernel::Avx2 | Kernel::Avx512 => {
                        // SAFETY: the CPU has AVX2 (asserted above); the
                        // traversal is safe code compiled for it.
                        unsafe { s.run_avx2() }
                    }
                    _ => s.run(),
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

/// One query's search.
struct Search<'a> {
    tree: &'a KdTree,
    /// Whether every vector of the tree lies in `range`.
    whole: bool,
    /// The query's components, zero-padded like the points.
    q: &'a [u8; MAX_DIMS],
    weight: &'a [u64],
    /// The weight of every component, when they all have the same.
    uniform: Option<u64>,
    metric: Metric,
    range: std::ops::Range<u64>,
    k: usize,
    worst: u64,
    /// The best so far, sorted by (distance, index).
    list: Vec<Hit>,
}

impl Search<'_> {
    #[inline(always)]
    fn term(&self, d: usize, gap: u64) -> u64 {
        self.weight[d]
            * match self.metric {
                Metric::L1 => gap,
                Metric::L2 => gap * gap,
            }
    }

    /// Largest distance a vector may have and still enter the list.
    #[inline(always)]
    fn limit(&self) -> u64 {
        if self.list.len() == self.k {
            self.list[self.k - 1].dist
        } else {
            self.worst.saturating_sub(1)
        }
    }

    /// The least distance from the query to any vector of node `n`: the
    /// distance to its bounding box, tighter than the distance to the cell
    /// its splits bound (Arya and Mount's incremental bound), since the box
    /// lies inside the cell.
    #[inline(always)]
    fn box_bound(&self, n: u32) -> u64 {
        let [lo, hi] = &self.tree.boxes[n as usize];
        let gap = |d: usize| lo[d].saturating_sub(self.q[d]) | self.q[d].saturating_sub(hi[d]);
        match self.uniform {
            // The padding is zero in the box and the query, so it adds nothing.
            Some(w) => {
                let mut sum = 0u32;
                for d in 0..MAX_DIMS {
                    let g = u32::from(gap(d));
                    sum += match self.metric {
                        Metric::L1 => g,
                        Metric::L2 => g * g,
                    };
                }
                w * u64::from(sum)
            }
            None => (0..self.tree.dims)
                .map(|d| self.term(d, u64::from(gap(d))))
                .sum(),
        }
    }

    /// The search from the root: depth first, each node's children nearer
    /// box first, a node visited only while its box may still hold a vector
    /// within the limit (the limit tightens as the list fills, so a far
    /// child is tested again when its turn comes).
    #[inline(always)]
    fn run(&mut self) {
        let root = self.box_bound(0);
        // Equal to the limit may still win on a lower index.
        if root > self.limit() {
            return;
        }
        let mut stack: Vec<(u32, u64)> = Vec::with_capacity(64);
        stack.push((0, root));
        while let Some((n, bound)) = stack.pop() {
            if bound > self.limit() {
                continue;
            }
            let node = self.tree.nodes[n as usize];
            if node.left == NONE {
                self.leaf(node.lo as usize..node.hi as usize);
                continue;
            }
            let (a, b) = (self.box_bound(node.left), self.box_bound(node.right));
            let ((near, dn), (far, df)) = if a <= b {
                ((node.left, a), (node.right, b))
            } else {
                ((node.right, b), (node.left, a))
            };
            if df <= self.limit() {
                stack.push((far, df));
            }
            if dn <= self.limit() {
                stack.push((near, dn));
            }
        }
    }

    /// [`Search::run`] compiled for AVX2: the box bounds and leaf distances
    /// of 16 bytes become whole-register operations.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2(&mut self) {
        self.run();
    }

    #[inline(always)]
    fn leaf(&mut self, span: std::ops::Range<usize>) {
        let dims = self.tree.dims;
        for p in span {
            if !self.whole && !self.range.contains(&self.tree.index[p]) {
                continue;
            }
            let limit = self.limit();
            let v = &self.tree.points[p];
            let dist = match self.uniform {
                // The padding is zero in both, so it adds nothing.
                Some(w) => w * u64::from(padded_sum(v, self.q, self.metric)),
                None => {
                    let mut dist = 0u64;
                    for (d, (&a, &b)) in v[..dims].iter().zip(self.q).enumerate() {
                        dist += self.term(d, u64::from(a.abs_diff(b)));
                        if dist > limit {
                            break;
                        }
                    }
                    dist
                }
            };
            if dist > limit || dist >= self.worst {
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
        }
    }
}

/// `Σ |a − b|` (L1) or `Σ (a − b)²` (L2) over two padded vectors: a loop of
/// fixed length over bytes, which the compiler turns into a few vector
/// instructions.
#[inline(always)]
fn padded_sum(a: &[u8; MAX_DIMS], b: &[u8; MAX_DIMS], metric: Metric) -> u32 {
    let mut sum = 0u32;
    match metric {
        Metric::L1 => {
            for i in 0..MAX_DIMS {
                sum += u32::from(a[i].abs_diff(b[i]));
            }
        }
        Metric::L2 => {
            for i in 0..MAX_DIMS {
                let d = u32::from(a[i].abs_diff(b[i]));
                sum += d * d;
            }
        }
    }
    sum
}
