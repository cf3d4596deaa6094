//! Synthesis levels that hold exemplar coordinates, not colours (Lefebvre and
//! Hoppe, as Manke and Wünsche §3–4 use them): initialisation, coordinate
//! upsampling and the jitter of §4.2.
//!
//! The exemplar is a Gaussian *stack* (every level at full size, blurred
//! more and more), so coordinates are always full-size exemplar pixels and
//! any exemplar size works, not only powers of two. On level `i` of `L`
//! (0 coarsest) a coordinate step is `h_i = 2^(L−1−i)` pixels; with a
//! power-of-two pyramid this is exactly the paper's `(2·S + Δ) mod s_e`.

/// A level of exemplar coordinates, row by row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CoordMap {
    pub width: usize,
    pub height: usize,
    pub coords: Vec<[u32; 2]>,
}

impl CoordMap {
    pub fn get(&self, x: usize, y: usize) -> [u32; 2] {
        self.coords[y * self.width + x]
    }

    /// The coarsest level's start (§4.1): `S(P) = P mod s_e`, each step `h`
    /// pixels of the exemplar.
    pub fn initial(width: usize, height: usize, exemplar: (usize, usize), h: u32) -> Self {
        let (ew, eh) = (exemplar.0 as u64, exemplar.1 as u64);
        let coords = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| {
                [
                    (x as u64 * u64::from(h) % ew) as u32,
                    (y as u64 * u64::from(h) % eh) as u32,
                ]
            })
            .collect();
        Self {
            width,
            height,
            coords,
        }
    }

    /// A random start: each pixel an exemplar pixel drawn from a hash of its
    /// position and `seed`, uniform over the exemplar, so no offset between
    /// output and exemplar is favoured (the tiled start of §4.1 gives every
    /// pixel the offset 0, which coherent corrections keep: a copy of the
    /// exemplar, every offset a multiple of the coarsest step).
    pub fn random(width: usize, height: usize, exemplar: (usize, usize), seed: u64) -> Self {
        let coords = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| random_pixel([x as i64, y as i64, 0], exemplar, seed))
            .collect();
        Self {
            width,
            height,
            coords,
        }
    }

    /// Coordinate upsampling: each pixel's four children take its coordinate
    /// plus `h·Δ`, `Δ ∈ {0, 1}²`, wrapped into the exemplar; the child level is
    /// `2w × 2h` cropped to `(width, height)`.
    pub fn upsample(&self, width: usize, height: usize, exemplar: (usize, usize), h: u32) -> Self {
        let (ew, eh) = (exemplar.0 as u32, exemplar.1 as u32);
        let coords = (0..height)
            .flat_map(|y| (0..width).map(move |x| (x, y)))
            .map(|(x, y)| {
                let p = self.get((x / 2).min(self.width - 1), (y / 2).min(self.height - 1));
                let (dx, dy) = ((x % 2) as u32, (y % 2) as u32);
                [(p[0] + h * dx) % ew, (p[1] + h * dy) % eh]
            })
            .collect();
        Self {
            width,
            height,
            coords,
        }
    }

    /// Adds the jitter of level `level` with strength `r ∈ [0, 1]`, in steps of
    /// `h` pixels, wrapped into the exemplar.
    pub fn jitter(&mut self, exemplar: (usize, usize), h: u32, r: f64, level: u32, seed: u64) {
        let (ew, eh) = (exemplar.0 as i64, exemplar.1 as i64);
        let w = self.width;
        for (i, c) in self.coords.iter_mut().enumerate() {
            let [jx, jy] = jitter_offset([(i % w) as i64, (i / w) as i64, 0], r, level, seed);
            c[0] = (i64::from(c[0]) + jx * i64::from(h)).rem_euclid(ew) as u32;
            c[1] = (i64::from(c[1]) + jy * i64::from(h)).rem_euclid(eh) as u32;
        }
    }
}

/// `v` modulo `n` (`n > 0`), for a neighbour's place on a wrapping lattice
/// or exemplar: most lie inside, so the division is only paid at the
/// border (it was a tenth of a solid's time).
#[inline]
pub fn wrap(v: i64, n: usize) -> usize {
    if (0..n as i64).contains(&v) {
        v as usize
    } else {
        v.rem_euclid(n as i64) as usize
    }
}

/// The jitter of §4.2 at position `p` (2-D positions have `p[2] = 0`):
/// `J(P) = ⌊j + k⌋` with `j = H(P)·lerp(0.5, 1, r)` and, per axis,
/// `k = lerp(0.5, 2/3, r)` where `j ≥ 0`, else `1 − lerp(0.5, 2/3, r)`.
/// `H` hashes the position, level and seed to `[−1, 1)²`, so the jitter does
/// not depend on the order pixels are visited. At `r = 0` there is no jitter;
/// at `r = 1` each axis is −1, 0 or +1 with probability 1/3 each.
pub fn jitter_offset(p: [i64; 3], r: f64, level: u32, seed: u64) -> [i64; 2] {
    let lerp = |a: f64, b: f64, t: f64| a + t * (b - a);
    let h = position_hash(p, level, seed);
    let scale = lerp(0.5, 1.0, r);
    let k = lerp(0.5, 2.0 / 3.0, r);
    let axis = |u: f64| {
        let j = u * scale;
        (j + if j >= 0.0 { k } else { 1.0 - k }).floor() as i64
    };
    [axis(h[0]), axis(h[1])]
}

/// An exemplar pixel drawn from a hash of position `p` (2-D positions have
/// `p[2] = 0`) and `seed`, uniform over a `exemplar.0`×`exemplar.1` exemplar:
/// the random start of a plane or a volume.
pub fn random_pixel(p: [i64; 3], exemplar: (usize, usize), seed: u64) -> [u32; 2] {
    let u = position_hash(p, u32::MAX, seed);
    let pick = |v: f64, n: usize| (((v + 1.0) / 2.0 * n as f64) as usize).min(n - 1) as u32;
    [pick(u[0], exemplar.0), pick(u[1], exemplar.1)]
}

/// Two values in `[−1, 1)` from a position, a level and a seed (SplitMix64).
pub fn position_hash(p: [i64; 3], level: u32, seed: u64) -> [f64; 2] {
    let mix = |mut z: u64| {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let mut z = mix(seed ^ u64::from(level).wrapping_mul(0xA24B_AED4_963E_E407));
    for c in p {
        z = mix(z ^ c as u64);
    }
    let a = mix(z);
    let b = mix(a);
    let unit = |v: u64| (v >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
    [unit(a), unit(b)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The fast path agrees with the division everywhere, inside the
        /// lattice, across its border and many sides away.
        #[test]
        fn wrap_is_the_euclidean_remainder(v in -1_000_000i64..1_000_000, n in 1usize..5000) {
            prop_assert_eq!(wrap(v, n), v.rem_euclid(n as i64) as usize);
        }
    }

    #[test]
    fn at_full_strength_each_axis_splits_into_thirds() {
        let mut counts = [[0usize; 3]; 2];
        let n = 300 * 300;
        for y in 0..300 {
            for x in 0..300 {
                let j = jitter_offset([x, y, 0], 1.0, 3, 7);
                for a in 0..2 {
                    assert!((-1..=1).contains(&j[a]));
                    counts[a][(j[a] + 1) as usize] += 1;
                }
            }
        }
        for axis in counts {
            for c in axis {
                let share = c as f64 / n as f64;
                assert!((share - 1.0 / 3.0).abs() < 0.01, "{axis:?}");
            }
        }
    }

    #[test]
    fn no_jitter_at_zero_strength() {
        for x in 0..50 {
            for y in 0..50 {
                assert_eq!(jitter_offset([x, y, 0], 0.0, 1, 1), [0, 0]);
            }
        }
    }

    #[test]
    fn upsampling_a_power_of_two_exemplar_is_the_paper_s_formula() {
        // Pyramid coordinates on level i are stack coordinates / h_i.
        let e = (16, 16);
        let coarse = CoordMap::initial(4, 4, e, 4);
        let fine = coarse.upsample(8, 8, e, 2);
        for y in 0..8 {
            for x in 0..8 {
                let p = coarse.get(x / 2, y / 2).map(|v| v / 4);
                let expect = [
                    (2 * p[0] + (x % 2) as u32) % 8,
                    (2 * p[1] + (y % 2) as u32) % 8,
                ];
                assert_eq!(fine.get(x, y).map(|v| v / 2), expect);
            }
        }
    }
}
