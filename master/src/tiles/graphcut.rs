//! Joining an intermediate ω-tile with its matching patch (Dong, Zhou and
//! Paul §3, after Kwatra et al.'s graph cuts): a minimum cut between the two
//! inside a circle, so the tile's border ring stays the tile's, then Poisson
//! smoothing (Pérez et al.) of the seams that remain.

use crate::imaging::ColorImage;

use crate::seams::rgb_distance;

/// A minimum s–t cut: its value and, per node, whether it is on the source's
/// side. `edges` are directed `(from, to, capacity)`; give both directions for
/// an undirected edge, and parallel edges add up.
///
/// The maximum flow is Boykov and Kolmogorov's algorithm: a search tree grows
/// from each terminal; where they touch, the path is augmented, and nodes cut
/// off by saturated arcs are re-adopted or freed. The source side is what the
/// residual graph still reaches. The `pathfinding` crate's Edmonds–Karp took
/// 1.6 s per 80² tile here, too slow for a 38-tile set; it stays in the tests
/// as the reference this is checked against, with brute force on small graphs.
pub fn min_cut(
    nodes: usize,
    source: usize,
    sink: usize,
    edges: &[(usize, usize, i64)],
) -> (i64, Vec<bool>) {
    let mut g = Network::new(nodes, edges);
    let value = g.boykov_kolmogorov(source, sink);
    (value, g.reachable(source))
}

const NONE: usize = usize::MAX;
/// The parent of a terminal.
const ROOT: usize = usize::MAX - 1;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Tree {
    Free,
    Source,
    Sink,
}

/// Arcs in pairs: arc `2k` is edge `k`, arc `2k + 1` its reverse (capacity 0),
/// so `a ^ 1` is the reverse of `a`; `head`/`next` list each node's arcs.
struct Network {
    head: Vec<usize>,
    next: Vec<usize>,
    to: Vec<usize>,
    cap: Vec<i64>,
}

impl Network {
    fn new(nodes: usize, edges: &[(usize, usize, i64)]) -> Self {
        let mut g = Self {
            head: vec![NONE; nodes],
            next: Vec::with_capacity(2 * edges.len()),
            to: Vec::with_capacity(2 * edges.len()),
            cap: Vec::with_capacity(2 * edges.len()),
        };
        for &(a, b, c) in edges {
            for (from, dest, c) in [(a, b, c), (b, a, 0)] {
                g.to.push(dest);
                g.cap.push(c);
                g.next.push(g.head[from]);
                g.head[from] = g.to.len() - 1;
            }
        }
        g
    }

    fn arcs(&self, v: usize) -> impl Iterator<Item = usize> + '_ {
        let first = Some(self.head[v]).filter(|&e| e != NONE);
        std::iter::successors(first, move |&e| Some(self.next[e]).filter(|&n| n != NONE))
    }

    /// Whether flow can go from `p`'s tree to its neighbour along arc `a`
    /// (out of `p`): forwards in the source tree, backwards in the sink tree.
    fn open(&self, tree: Tree, a: usize) -> bool {
        match tree {
            Tree::Source => self.cap[a] > 0,
            _ => self.cap[a ^ 1] > 0,
        }
    }

    fn boykov_kolmogorov(&mut self, source: usize, sink: usize) -> i64 {
        let n = self.head.len();
        let mut tree = vec![Tree::Free; n];
        // parent[v]: in the source tree the arc parent → v, in the sink tree
        // the arc v → parent.
        let mut parent = vec![NONE; n];
        let parent_node = |to: &[usize], tree: Tree, a: usize| match tree {
            Tree::Source => to[a ^ 1],
            _ => to[a],
        };
        tree[source] = Tree::Source;
        tree[sink] = Tree::Sink;
        parent[source] = ROOT;
        parent[sink] = ROOT;
        let mut active = std::collections::VecDeque::from([source, sink]);
        let mut orphans: Vec<usize> = Vec::new();
        let mut flow = 0i64;
        while let Some(&p) = active.front() {
            if tree[p] == Tree::Free {
                active.pop_front();
                continue;
            }
            // Growth: claim free neighbours; stop at one of the other tree.
            let mut meet = None;
            for a in self.arcs(p) {
                if !self.open(tree[p], a) {
                    continue;
                }
                let q = self.to[a];
                if tree[q] == Tree::Free {
                    tree[q] = tree[p];
                    parent[q] = if tree[p] == Tree::Source { a } else { a ^ 1 };
                    active.push_back(q);
                } else if tree[q] != tree[p] {
                    // The arc from the source tree to the sink tree.
                    meet = Some(if tree[p] == Tree::Source { a } else { a ^ 1 });
                    break;
                }
            }
            let Some(m) = meet else {
                active.pop_front();
                continue;
            };
            // Augmentation along source … → m → … sink.
            let (s_end, t_end) = (self.to[m ^ 1], self.to[m]);
            let mut push = self.cap[m];
            for (start, side) in [(s_end, Tree::Source), (t_end, Tree::Sink)] {
                let mut v = start;
                while parent[v] != ROOT {
                    push = push.min(self.cap[parent[v]]);
                    v = parent_node(&self.to, side, parent[v]);
                }
            }
            self.cap[m] -= push;
            self.cap[m ^ 1] += push;
            for (start, side) in [(s_end, Tree::Source), (t_end, Tree::Sink)] {
                let mut v = start;
                while parent[v] != ROOT {
                    let a = parent[v];
                    let u = parent_node(&self.to, side, a);
                    self.cap[a] -= push;
                    self.cap[a ^ 1] += push;
                    if self.cap[a] == 0 {
                        parent[v] = NONE;
                        orphans.push(v);
                    }
                    v = u;
                }
            }
            flow += push;
            // Adoption: an orphan takes a neighbour of its tree that still
            // leads to the terminal, or is freed and lets go of its children.
            while let Some(o) = orphans.pop() {
                let side = tree[o];
                let rooted = |parent: &[usize], mut v: usize| loop {
                    match parent[v] {
                        ROOT => return true,
                        NONE => return false,
                        a => v = parent_node(&self.to, side, a),
                    }
                };
                let adopt = self.arcs(o).find(|&a| {
                    let q = self.to[a];
                    tree[q] == side && self.open(side, a ^ 1) && rooted(&parent, q)
                });
                if let Some(a) = adopt {
                    parent[o] = a ^ 1;
                    if side == Tree::Sink {
                        parent[o] = a;
                    }
                    continue;
                }
                for a in self.arcs(o) {
                    let q = self.to[a];
                    if tree[q] != side {
                        continue;
                    }
                    if self.open(side, a ^ 1) {
                        active.push_back(q);
                    }
                    let pa = parent[q];
                    if pa != NONE && pa != ROOT && parent_node(&self.to, side, pa) == o {
                        parent[q] = NONE;
                        orphans.push(q);
                    }
                }
                tree[o] = Tree::Free;
            }
        }
        flow
    }

    /// The nodes the residual graph reaches from `source`.
    fn reachable(&self, source: usize) -> Vec<bool> {
        let mut side = vec![false; self.head.len()];
        side[source] = true;
        let mut todo = vec![source];
        while let Some(v) = todo.pop() {
            for e in self.arcs(v) {
                if self.cap[e] > 0 && !side[self.to[e]] {
                    side[self.to[e]] = true;
                    todo.push(self.to[e]);
                }
            }
        }
        side
    }
}

/// What the merge of a tile with its matching patch gave.
#[derive(Clone, Debug)]
pub struct Merge {
    pub image: ColorImage,
    /// Per pixel, whether it came from the matching patch.
    pub from_patch: Vec<bool>,
    /// The cut's cost (the sum of the seam's edge weights, ×16).
    pub cut: i64,
}

/// Merges `patch` into the intermediate `tile` (both T×T, quarters meeting at
/// the centre) along a minimum-cost seam.
///
/// Pixels outside the tile's inscribed circle are tied to the tile (the
/// circle constraint: the border ring, which neighbouring tiles continue,
/// never changes); a disc at the centre and the quarter junctions out to
/// two thirds of the radius are tied to the patch, so the junction cross is
/// covered. Between them, the edge of neighbours `s`, `t` costs
/// `‖A(s) − B(s)‖ + ‖A(t) − B(t)‖` (Kwatra et al.), and the cheapest cut
/// decides which pixels take the patch.
pub fn merge(tile: &ColorImage, patch: &ColorImage) -> Merge {
    let (w, h) = (tile.width, tile.height);
    debug_assert_eq!((w, h), (patch.width, patch.height));
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let radius = cx.min(cy) - 1.0;
    let n = w * h;
    let (source, sink) = (n, n + 1);
    let err: Vec<f32> = (0..n)
        .map(|p| rgb_distance(tile.get(p % w, p / w), patch.get(p % w, p / w)))
        .collect();
    let big = i64::MAX / 4;
    let mut edges = Vec::with_capacity(6 * n);
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
            let d = (dx * dx + dy * dy).sqrt();
            let on_cross = dx.abs() <= 1.0 || dy.abs() <= 1.0;
            if d > radius {
                edges.push((source, p, big));
            } else if d <= radius / 4.0 || (on_cross && d <= radius * 2.0 / 3.0) {
                edges.push((p, sink, big));
            }
            for q in [(x + 1 < w).then(|| p + 1), (y + 1 < h).then(|| p + w)]
                .into_iter()
                .flatten()
            {
                let c = ((err[p] + err[q]) * 16.0).round() as i64 + 1;
                edges.push((p, q, c));
                edges.push((q, p, c));
            }
        }
    }
    let (cut, side) = min_cut(n + 2, source, sink, &edges);
    let from_patch: Vec<bool> = side[..n].iter().map(|&s| !s).collect();
    let mut image = tile.clone();
    for (p, &b) in from_patch.iter().enumerate() {
        if b {
            image.set(p % w, p / w, patch.get(p % w, p / w));
        }
    }
    Merge {
        image,
        from_patch,
        cut,
    }
}

/// Poisson smoothing of seams (Pérez et al.): inside the 1-pixel border ring,
/// which stays fixed, solve for the image whose gradients are the given
/// image's, except across the `seam` pairs, where the gradient is taken as 0,
/// so the step there is spread over its surroundings. `seam(p, q)` says
/// whether neighbours `p` and `q` (pixel indices) lie on two sides of a seam.
/// Gauss–Seidel with over-relaxation, `iterations` sweeps.
pub fn poisson_smooth(
    img: &ColorImage,
    seam: impl Fn(usize, usize) -> bool,
    iterations: usize,
) -> ColorImage {
    let (w, h) = (img.width, img.height);
    if w < 3 || h < 3 {
        return img.clone();
    }
    let mut out = img.clone();
    let neighbours = |p: usize| [p - 1, p + 1, p - w, p + w];
    let inner = |p: usize| (1..w - 1).contains(&(p % w)) && (1..h - 1).contains(&(p / w));
    // Which of each inner pixel's four neighbours lie across a seam: asked
    // once, not once per sweep and channel.
    let across: Vec<[bool; 4]> = (0..w * h)
        .map(|p| {
            if inner(p) {
                neighbours(p).map(|q| seam(p, q))
            } else {
                [false; 4]
            }
        })
        .collect();
    for ch in 0..3 {
        let g: Vec<f32> = (0..w * h)
            .map(|p| f32::from(img.get(p % w, p / w)[ch]))
            .collect();
        // The guidance gradient towards each neighbour (0 across a seam).
        let guide: Vec<[f32; 4]> = (0..w * h)
            .map(|p| {
                if !inner(p) {
                    return [0.0; 4];
                }
                let qs = neighbours(p);
                std::array::from_fn(|k| if across[p][k] { 0.0 } else { g[p] - g[qs[k]] })
            })
            .collect();
        let mut f = g.clone();
        let omega = 1.8f32;
        for _ in 0..iterations {
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let p = y * w + x;
                    let mut sum = 0.0;
                    for (q, v) in neighbours(p).into_iter().zip(guide[p]) {
                        sum += f[q] + v;
                    }
                    f[p] += omega * (sum / 4.0 - f[p]);
                }
            }
        }
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut c = out.get(x, y);
                c[ch] = f[y * w + x].round().clamp(0.0, 255.0) as u8;
                out.set(x, y, c);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A seeded linear congruential generator of values in `0..m`.
    fn lcg(mut seed: u64) -> impl FnMut(u64) -> u64 {
        move |m| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) % m
        }
    }

    /// The capacity of the edges from the source side to the other.
    fn crossing(edges: &[(usize, usize, i64)], side: &[bool]) -> i64 {
        edges
            .iter()
            .filter(|&&(a, b, _)| side[a] && !side[b])
            .map(|&(_, _, c)| c)
            .sum()
    }

    /// The least cut by trying every split of the inner nodes.
    fn brute_force(nodes: usize, s: usize, t: usize, edges: &[(usize, usize, i64)]) -> i64 {
        let inner: Vec<usize> = (0..nodes).filter(|&v| v != s && v != t).collect();
        (0..1u32 << inner.len())
            .map(|mask| {
                let mut side = vec![false; nodes];
                side[s] = true;
                for (k, &v) in inner.iter().enumerate() {
                    side[v] = mask >> k & 1 == 1;
                }
                crossing(edges, &side)
            })
            .min()
            .unwrap()
    }

    /// The `pathfinding` crate's Edmonds–Karp maximum flow.
    fn edmonds_karp(nodes: usize, s: usize, t: usize, edges: &[(usize, usize, i64)]) -> i64 {
        let mut caps = std::collections::BTreeMap::new();
        for &(a, b, c) in edges {
            *caps.entry((a, b)).or_insert(0) += c;
        }
        let vertices: Vec<usize> = (0..nodes).collect();
        pathfinding::directed::edmonds_karp::edmonds_karp_sparse(&vertices, &s, &t, caps).1
    }

    #[test]
    fn grids_agree_with_edmonds_karp() {
        let mut next = lcg(3);
        for round in 0..20 {
            let (w, h) = (4 + next(27) as usize, 4 + next(27) as usize);
            let n = w * h;
            let mut edges = Vec::new();
            for p in 0..n {
                let c = next(50) as i64;
                if p % w + 1 < w {
                    edges.push((p, p + 1, c));
                    edges.push((p + 1, p, next(50) as i64));
                }
                if p + w < n {
                    edges.push((p, p + w, c + 3));
                    edges.push((p + w, p, next(50) as i64));
                }
                // Terminal links on the left and right edges, and a few inside.
                if p % w == 0 || next(20) == 0 {
                    edges.push((n, p, 20 + next(200) as i64));
                }
                if p % w == w - 1 || next(20) == 0 {
                    edges.push((p, n + 1, 20 + next(200) as i64));
                }
            }
            let (value, side) = min_cut(n + 2, n, n + 1, &edges);
            assert_eq!(
                value,
                edmonds_karp(n + 2, n, n + 1, &edges),
                "grid {round}: {w}x{h}"
            );
            assert_eq!(crossing(&edges, &side), value, "grid {round}");
        }
    }

    #[test]
    fn the_cut_equals_a_brute_force_minimum_cut_on_small_graphs() {
        let mut next = lcg(17);
        for _ in 0..300 {
            let nodes = 2 + next(9) as usize;
            let mut edges = Vec::new();
            for _ in 0..next(25) {
                let (a, b) = (next(nodes as u64) as usize, next(nodes as u64) as usize);
                if a != b {
                    edges.push((a, b, next(20) as i64));
                }
            }
            let (value, side) = min_cut(nodes, 0, nodes - 1, &edges);
            assert_eq!(value, brute_force(nodes, 0, nodes - 1, &edges), "{edges:?}");
            assert_eq!(
                value,
                edmonds_karp(nodes, 0, nodes - 1, &edges),
                "{edges:?}"
            );
            // The side found is a cut of that value.
            assert!(side[0] && !side[nodes - 1]);
            assert_eq!(crossing(&edges, &side), value);
        }
    }

    #[test]
    fn the_merge_keeps_the_border_ring_and_covers_the_centre() {
        let (w, h) = (24, 24);
        let tile =
            ColorImage::from_vec(w, h, (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect());
        let patch =
            ColorImage::from_vec(w, h, (0..w * h * 3).map(|i| (i * 13 % 241) as u8).collect());
        let m = merge(&tile, &patch);
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f64 + 0.5 - 12.0, y as f64 + 0.5 - 12.0);
                let d = (dx * dx + dy * dy).sqrt();
                if d > 11.0 {
                    assert_eq!(m.image.get(x, y), tile.get(x, y), "ring ({x}, {y})");
                }
                if d <= 11.0 / 4.0 {
                    assert_eq!(m.image.get(x, y), patch.get(x, y), "centre ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn poisson_smoothing_keeps_the_border_and_lowers_the_seam_step() {
        let (w, h) = (20, 12);
        // Two flat halves with a step of 100 between columns 9 and 10.
        let img = ColorImage::from_vec(
            w,
            h,
            (0..w * h)
                .flat_map(|p| [if p % w < 10 { 50 } else { 150 }; 3])
                .collect(),
        );
        let seam = |p: usize, q: usize| (p % w < 10) != (q % w < 10);
        let out = poisson_smooth(&img, seam, 300);
        for x in 0..w {
            assert_eq!(out.get(x, 0), img.get(x, 0));
            assert_eq!(out.get(x, h - 1), img.get(x, h - 1));
        }
        let step = |i: &ColorImage| i32::from(i.get(10, 6)[0]) - i32::from(i.get(9, 6)[0]);
        assert!(step(&out) < 20, "step {} after smoothing", step(&out));
    }
}
