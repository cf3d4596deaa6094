//! Lattice phase, shared by the methods that keep a grid sample's grid
//! (the block method, ARCHITECTURE §3.14; solids, §11): the grid's periods
//! and how far a copy offset lies from the lattice.

use anyhow::{ensure, Result};

/// The grid's periods along x and y, in sample pixels of the finest level;
/// 0 leaves that axis free (courses of brick whose joints along the course
/// do not keep one period).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Lattice {
    pub period: [f64; 2],
}

impl Lattice {
    /// Periods of at least 2 pixels and at most the sample's side, or 0 (that
    /// axis free), not both 0.
    pub fn validate(&self, sample: [usize; 2]) -> Result<()> {
        ensure!(
            self.period != [0.0, 0.0],
            "--lattice 0x0 keeps no phase; give the grid's period on at least one axis"
        );
        for (axis, (&p, &side)) in ["width", "height"]
            .iter()
            .zip(self.period.iter().zip(&sample))
        {
            if p == 0.0 {
                continue;
            }
            ensure!(
                p.is_finite() && p >= 2.0,
                "--lattice {axis} {p} must be at least 2 pixels (the grid's period: the distance from one joint to the next), or 0 to leave that axis free"
            );
            ensure!(
                p <= side as f64,
                "--lattice {axis} {p} is larger than the sample's {axis} {side}; give the period of one tile of the grid"
            );
        }
        Ok(())
    }

    /// How far, in tenths of a pixel of `level` (0 = finest), the copy
    /// `offset` lies from the lattice through `origin` (both canvas position
    /// less sample position on that level), rounded.
    pub fn phase_error(&self, offset: [i64; 2], origin: [i64; 2], level: usize) -> u32 {
        let scale = f64::from(1u32 << level.min(30));
        let off_axis = |axis: usize| self.axis_error(axis, offset[axis] - origin[axis], scale);
        let (ex, ey) = (off_axis(0), off_axis(1));
        (10.0 * (ex * ex + ey * ey).sqrt()).round() as u32
    }

    /// How far, in pixels, an offset `d` along `axis` lies from the nearest
    /// multiple of the period divided by `scale` (0 on a free axis).
    pub fn axis_error(&self, axis: usize, d: i64, scale: f64) -> f64 {
        if self.period[axis] == 0.0 {
            return 0.0;
        }
        let p = self.period[axis] / scale;
        let d = (d as f64).rem_euclid(p);
        d.min(p - d)
    }

    /// The multiple of the period along `axis` nearest to the offset `d`,
    /// in whole pixels of the finest level (`d` itself on a free axis).
    pub fn nearest(&self, axis: usize, d: i64) -> i64 {
        let p = self.period[axis];
        if p == 0.0 {
            return d;
        }
        ((d as f64 / p).round() * p).round() as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn periods_must_fit_the_sample() {
        let ok = Lattice {
            period: [32.0, 24.5],
        };
        assert!(ok.validate([256, 256]).is_ok());
        assert!(Lattice {
            period: [0.0, 29.0]
        }
        .validate([96, 96])
        .is_ok());
        for period in [[1.5, 32.0], [32.0, 300.0], [f64::NAN, 8.0], [0.0, 0.0]] {
            let e = Lattice { period }.validate([256, 256]).unwrap_err();
            assert!(e.to_string().contains("--lattice"), "{e}");
        }
    }

    proptest! {
        /// The error is zero on the lattice through the origin, periodic,
        /// symmetric about it, and scales with the level.
        #[test]
        fn phase_error_is_a_distance_to_the_lattice(
            px in 2u32..64, py in 2u32..64,
            ox in -500i64..500, oy in -500i64..500,
            dx in -40i64..40, dy in -40i64..40,
            kx in -5i64..5, ky in -5i64..5,
        ) {
            let l = Lattice { period: [f64::from(px), f64::from(py)] };
            let origin = [ox, oy];
            let on = [ox + kx * i64::from(px), oy + ky * i64::from(py)];
            prop_assert_eq!(l.phase_error(on, origin, 0), 0);
            let at = [ox + dx, oy + dy];
            let shifted = [at[0] + kx * i64::from(px), at[1] + ky * i64::from(py)];
            let e = l.phase_error(at, origin, 0);
            prop_assert_eq!(e, l.phase_error(shifted, origin, 0));
            prop_assert_eq!(e, l.phase_error([ox - dx, oy - dy], origin, 0));
            let bound = 10.0 * ((dx * dx + dy * dy) as f64).sqrt();
            prop_assert!(f64::from(e) <= bound.round() + 1e-9);
            // One level coarser the periods halve: an offset of twice the
            // period there is twice the finest period's lattice step.
            let l2 = Lattice { period: [f64::from(2 * px), f64::from(2 * py)] };
            prop_assert_eq!(l2.phase_error(at, origin, 1), e);
            // A free axis counts nothing: only the other axis's error is left.
            let rows = Lattice { period: [0.0, f64::from(py)] };
            let dyp = (oy + dy - oy).rem_euclid(i64::from(py));
            let ey = 10 * dyp.min(i64::from(py) - dyp) as u32;
            prop_assert_eq!(rows.phase_error(at, origin, 0), ey);
        }
    }

    proptest! {
        /// `nearest` lands on the lattice within half a period's rounding,
        /// `axis_error` is the distance to it, and a free axis keeps the
        /// offset.
        #[test]
        fn nearest_is_on_the_lattice_and_the_error_its_distance(
            p in 2.0f64..64.0, d in -2000i64..2000,
        ) {
            let l = Lattice { period: [p, 0.0] };
            let n = l.nearest(0, d);
            prop_assert!(l.axis_error(0, n, 1.0) <= 0.5 + 1e-9);
            prop_assert!(((n - d) as f64).abs() <= p / 2.0 + 0.5 + 1e-9);
            let e = l.axis_error(0, d, 1.0);
            prop_assert!(e <= p / 2.0 + 1e-9);
            prop_assert!((e - ((d as f64) - (d as f64 / p).round() * p).abs()).abs() < 1e-6);
            prop_assert_eq!(l.nearest(1, d), d);
            prop_assert_eq!(l.axis_error(1, d, 1.0), 0.0);
        }
    }
}
