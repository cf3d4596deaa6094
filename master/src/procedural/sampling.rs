//! Adaptive subdivision of a shader's parameter domain (Bourque–Dudek
//! §3.2.1), the samples of the catalogue.
//!
//! The domain is a box whose centre is the first sample. The cells with the
//! highest priority are split in half along their widest parameter (whole
//! numbers split between values) and their halves' centres rendered; a
//! half's priority is how far its centre's texture is from its parent's,
//! plus a small floor, times its width. So the catalogue is dense where the
//! texture changes fast with the parameters and sparse where it does not.
//! Cells are split in fixed batches, so the samples are the same for any
//! thread count.

use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::catalogue::{describe, unit_distance, Sample};
use super::descriptor::Structure;
use super::shaders::{Kind, Shader};
use crate::progress::Progress;

/// Catalogue neighbours averaged in the admissibility A(x).
const ADMISSIBILITY_NEIGHBOURS: usize = 6;
/// Cells split per round.
const BATCH: usize = 8;

/// A box of the parameter domain, `lo..=hi` per parameter.
#[derive(Clone, Debug)]
struct Cell {
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// The sample at the centre.
    centre: usize,
    /// The sample at the centre of the cell this one was split from.
    parent: usize,
}

impl Cell {
    /// The widest parameter as a fraction of its range, 0 if none can split.
    fn widest(&self, s: &Shader) -> (usize, f64) {
        let mut best = (0, 0.0);
        for (i, p) in s.params.iter().enumerate() {
            let w = match p.kind {
                Kind::Integer if self.hi[i] > self.lo[i] => {
                    (self.hi[i] - self.lo[i] + 1.0) / (p.span() + 1.0)
                }
                Kind::Integer => 0.0,
                _ => (self.hi[i] - self.lo[i]) / p.span(),
            };
            if w > best.1 {
                best = (i, w);
            }
        }
        best
    }

    fn centre_params(&self, s: &Shader) -> Vec<f64> {
        s.params
            .iter()
            .enumerate()
            .map(|(i, p)| match p.kind {
                Kind::Integer => ((self.lo[i] + self.hi[i]) / 2.0).floor(),
                _ => (self.lo[i] + self.hi[i]) / 2.0,
            })
            .collect()
    }

    fn halves(&self, dim: usize, kind: Kind) -> (Cell, Cell) {
        let (mut a, mut b) = (self.clone(), self.clone());
        a.parent = self.centre;
        b.parent = self.centre;
        match kind {
            Kind::Integer => {
                let m = ((self.lo[dim] + self.hi[dim]) / 2.0).floor();
                a.hi[dim] = m;
                b.lo[dim] = m + 1.0;
            }
            _ => {
                let m = (self.lo[dim] + self.hi[dim]) / 2.0;
                a.hi[dim] = m;
                b.lo[dim] = m;
            }
        }
        (a, b)
    }
}

/// A cell waiting to be split, ordered by priority then age.
struct Pending {
    priority: f64,
    order: usize,
    cell: Cell,
}

impl PartialEq for Pending {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == std::cmp::Ordering::Equal
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Pending {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.priority
            .total_cmp(&o.priority)
            .then(o.order.cmp(&self.order))
    }
}

/// The samples of one shader by adaptive subdivision; `progress` advances
/// per rendered sample.
pub fn sample_shader(
    s: &Shader,
    size: usize,
    budget: usize,
    progress: &dyn Progress,
) -> Vec<Sample> {
    let root = Cell {
        lo: s.params.iter().map(|p| p.min).collect(),
        hi: s
            .params
            .iter()
            .map(|p| match p.kind {
                // The periodic end is the start again: stop short of it.
                Kind::Periodic => p.max - p.span() / 64.0,
                _ => p.max,
            })
            .collect(),
        centre: 0,
        parent: 0,
    };
    let first = root.centre_params(s);
    let mut params = vec![first.clone()];
    let mut structures = vec![describe(s, &first, size)];
    progress.advance(1);
    let mut heap = BinaryHeap::new();
    let mut order = 0;
    heap.push(Pending {
        priority: 1.0,
        order,
        cell: root,
    });
    while params.len() < budget && !heap.is_empty() {
        // The batch's halves, then their centres rendered in parallel.
        let mut halves = Vec::new();
        while halves.len() < 2 * BATCH {
            let Some(p) = heap.pop() else { break };
            let (dim, width) = p.cell.widest(s);
            if width == 0.0 {
                continue;
            }
            let (a, b) = p.cell.halves(dim, s.params[dim].kind);
            halves.push(a);
            halves.push(b);
        }
        if halves.is_empty() {
            break;
        }
        let room = budget - params.len();
        let mut fresh = Vec::new();
        for h in &mut halves {
            let c = h.centre_params(s);
            if let Some(i) = params.iter().position(|q| q == &c) {
                h.centre = i;
            } else if let Some(i) = fresh.iter().position(|q| q == &c) {
                h.centre = params.len() + i;
            } else if fresh.len() < room {
                h.centre = params.len() + fresh.len();
                fresh.push(c);
            } else {
                // Over budget: this half is not sampled.
                h.centre = usize::MAX;
            }
        }
        let described: Vec<Structure> = fresh
            .par_iter()
            .map(|c| {
                let d = describe(s, c, size);
                progress.advance(1);
                d
            })
            .collect();
        params.extend(fresh);
        structures.extend(described);
        for h in halves {
            if h.centre == usize::MAX {
                continue;
            }
            let d = structures[h.centre].distance(&structures[h.parent]);
            let (_, width) = h.widest(s);
            order += 1;
            heap.push(Pending {
                priority: (d + 0.05) * width,
                order,
                cell: h,
            });
        }
    }
    let admissibility = admissibility(s, &params, &structures);
    params
        .into_iter()
        .zip(structures)
        .zip(admissibility)
        .map(|((params, structure), admissibility)| Sample {
            params,
            structure,
            admissibility,
        })
        .collect()
}

/// A(x) of every sample over its nearest catalogue neighbours (§3.2.1).
fn admissibility(s: &Shader, params: &[Vec<f64>], structures: &[Structure]) -> Vec<f64> {
    (0..params.len())
        .into_par_iter()
        .map(|i| {
            let mut near: Vec<(f64, usize)> = (0..params.len())
                .filter(|&j| j != i)
                .map(|j| (unit_distance(s, &params[i], &params[j]), j))
                .filter(|(d, _)| *d > 0.0)
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            near.truncate(ADMISSIBILITY_NEIGHBOURS);
            if near.is_empty() {
                return 0.0;
            }
            near.iter()
                .map(|&(d, j)| (1.0 - structures[i].distance(&structures[j])) / d)
                .sum::<f64>()
                / near.len() as f64
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::by_name;
    use crate::progress::Silent;
    use std::collections::HashSet;

    #[test]
    fn subdivision_is_deterministic_and_covers_integer_values() {
        let s = by_name("bricks").unwrap();
        let [one, two] = crate::procedural::one_and_two_threads();
        let a = one.install(|| sample_shader(s, 48, 40, &Silent));
        let b = two.install(|| sample_shader(s, 48, 40, &Silent));
        assert_eq!(a, b);
        assert_eq!(a.len(), 40);
        let rows: HashSet<i64> = a.iter().map(|x| x.params[0] as i64).collect();
        assert!(rows.len() >= 3, "{rows:?}");
        for x in &a {
            assert_eq!(x.params[0].fract(), 0.0);
            assert!(x.admissibility.is_finite() && x.admissibility > 0.0);
        }
    }
}
