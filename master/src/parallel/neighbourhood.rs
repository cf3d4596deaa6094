//! The neighbourhoods compared during correction (Manke–Wünsche §3, Fig. 2).
//!
//! Neighbourhoods are sets of points in units of the level's step `h`, each
//! the mean of some pixels' appearance vectors:
//! - `Full(5)`, `Full(7)`: every pixel of the 5×5 or 7×7 window;
//! - `Reduced`: the four diagonal points (±1, ±1), each the mean of the
//!   diagonal pixel and the two axis pixels next to it (Lefebvre and Hoppe
//!   2006);
//! - `Half` (Manke–Wünsche §5.4, Fig. 2, which shows only a picture): the
//!   reduced four, the centre as the mean of the 3×3 pixels round it, and
//!   the four axis points (±2, 0), (0, ±2), each the mean of the three
//!   pixels across the axis there. Nine averaged points, a superset of the
//!   reduced neighbourhood, covering the 5×5 window. A centre of the one
//!   pixel (tried first) weighed a ninth of the match on a raw, jittered
//!   value and held the corrections to it: fidelity within 1.3× of the
//!   block method on 1 of 22 samples, against 8 with the 3×3 mean (10
//!   with the copy guard and finest passes `synth` gives it; ARCHITECTURE
//!   §10).

/// The neighbourhood compared during correction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Neighbourhood {
    Reduced,
    Half,
    Full(usize),
}

impl Neighbourhood {
    /// The name the command line uses for it.
    pub fn name(self) -> String {
        match self {
            Self::Reduced => "reduced".into(),
            Self::Half => "half".into(),
            Self::Full(n) => n.to_string(),
        }
    }

    /// Points: each a list of pixel offsets whose values are averaged.
    pub fn points(self) -> Vec<Vec<[i32; 2]>> {
        let diag = |sx: i32, sy: i32| vec![[sx, sy], [sx, 0], [0, sy]];
        let reduced = vec![diag(-1, -1), diag(1, -1), diag(-1, 1), diag(1, 1)];
        match self {
            Self::Reduced => reduced,
            Self::Half => {
                let mut p = reduced;
                p.push(
                    (-1..=1)
                        .flat_map(|y| (-1..=1).map(move |x| [x, y]))
                        .collect(),
                );
                for (ax, ay) in [(-2, 0), (2, 0), (0, -2), (0, 2)] {
                    p.push(if ax != 0 {
                        vec![[ax, -1], [ax, 0], [ax, 1]]
                    } else {
                        vec![[-1, ay], [0, ay], [1, ay]]
                    });
                }
                p
            }
            Self::Full(n) => {
                let r = (n / 2) as i32;
                (-r..=r)
                    .flat_map(|y| (-r..=r).map(move |x| vec![[x, y]]))
                    .collect()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_half_reduced_neighbourhood_holds_the_reduced_one() {
        let r = Neighbourhood::Reduced.points();
        let h = Neighbourhood::Half.points();
        assert_eq!(h.len(), 9);
        assert!(r.iter().all(|p| h.contains(p)));
        // Every point of the reduced and half neighbourhoods is a mean: a
        // single raw pixel would carry its jitter into the match.
        for n in [Neighbourhood::Reduced, Neighbourhood::Half] {
            assert!(n.points().iter().all(|p| p.len() >= 3), "{n:?}");
        }
        let centre: Vec<[i32; 2]> = (-1..=1)
            .flat_map(|y| (-1..=1).map(move |x| [x, y]))
            .collect();
        assert!(h.contains(&centre));
        assert_eq!(Neighbourhood::Full(7).points().len(), 49);
    }
}
