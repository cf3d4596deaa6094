//! The periods of a texture, read from its autocorrelation (Bourque–Dudek
//! §3.3: the power spectrum is what tells textures apart; its inverse
//! transform, the autocorrelation, puts the fundamental period of each
//! direction at its first peak, where the spectrum shows harmonics too).
//!
//! Used before any colour is fitted (§3.2.1): the periods seed the counts
//! and angles of the shaders' starting points, and [`Periodicity::distance`]
//! is the structure term that ranks shader families: planks repeat in one
//! direction, a grid of bricks in two.

use super::shaders::{Layout, Shader};
use crate::filters::{autocorrelation, box_blur_2d};

/// Directions in which the period is read, over 180°.
pub const DIRECTIONS: usize = 36;
/// Shortest period read, in pixels.
const MIN_PERIOD: f64 = 3.0;
/// A peak counts when it rises this far above the lowest correlation
/// before it.
const PROMINENCE: f64 = 0.08;
/// The period is the first peak at least this share of the highest one in
/// the direction (a weaker earlier bump is texture within the period).
const FIRST_PEAK_SHARE: f64 = 0.6;

/// The directions [`Periodicity::across`] chooses from repeat at least
/// this share of the strongest one's strength. Along a grid's axis the lag
/// runs inside the other axis's ridge, so the rise above the lows is half
/// or less of an oblique direction's: a higher share left only oblique
/// directions, whose crossings of the rows come at the row period over the
/// sine (a 24-row facade read as 20 rows at 60°).
const ACROSS_SHARE: f64 = 0.5;

/// The widest angle, in degrees, from a direction at which another
/// direction's period still bears out its lines ([`support`]).
const SUPPORT_FAN: f64 = 60.0;
/// How far (log ratio) a direction's period may differ from the one lines
/// across another direction predict and still bear it out.
const SUPPORT_TOLERANCE: f64 = 0.1;

/// A target whose tones' separation ([`super::pieces`]) reaches this shows
/// scattered features: a scattered shader's count is seeded from its pieces.
pub const SCATTERED: f64 = 0.5;

/// The first clear autocorrelation peak of one direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// Lag of the peak in pixels (0 when there is none).
    pub period: f64,
    /// Its height above the lowest correlation before it (0: no period).
    pub strength: f64,
}

/// The periods of a square grey image.
#[derive(Clone, Debug)]
pub struct Periodicity {
    /// Side of the analysed image in pixels.
    pub size: usize,
    /// Per direction k, at k·180/[`DIRECTIONS`] degrees from the x axis
    /// towards y (image rows go down): the first peak.
    pub lines: Vec<Peak>,
    /// Per direction, the first peak that [`repeats`]: the period of
    /// courses and lines, without the broad hump of the grain within one
    /// tile (what seeds counts; `lines` is what the structure term compares,
    /// and scattered features' spacing is such a hump).
    pub courses: Vec<Peak>,
    /// The first peak of the correlation averaged over all directions.
    pub radial: Peak,
    /// The features' frequency in cycles per image
    /// ([`super::arrangement::feature_frequency`]; 0 for a flat image).
    pub scale: f64,
    /// How one tone joins up while the other breaks into pieces, and into
    /// how many ([`super::pieces`]): scattered features against noise.
    pub pieces: super::pieces::Pieces,
}

impl Periodicity {
    /// The periods of the `n`×`n` grey values `v` (row-major), read from
    /// their high-pass (the values less a box blur of side n/16): joints
    /// and edges repeat where the shades of tiles between them do not.
    pub fn of_values(v: &[f64], n: usize) -> Self {
        let mut low = v.to_vec();
        if low.len() == n * n && n > 0 {
            let r = (n / 32).max(1);
            for _ in 0..2 {
                box_blur_2d(&mut low, n, n, r);
            }
        }
        let high: Vec<f64> = v.iter().zip(&low).map(|(a, b)| a - b).collect();
        let rho = autocorrelation(&high, (n, n));
        let m = 2 * n;
        let at = |x: f64, y: f64| -> f64 {
            // Bilinear over the wrapped lag grid.
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = (x - x0, y - y0);
            let idx = |a: f64, b: f64| {
                let (a, b) = (
                    (a as i64).rem_euclid(m as i64) as usize,
                    (b as i64).rem_euclid(m as i64) as usize,
                );
                rho[b * m + a]
            };
            idx(x0, y0) * (1.0 - fx) * (1.0 - fy)
                + idx(x0 + 1.0, y0) * fx * (1.0 - fy)
                + idx(x0, y0 + 1.0) * (1.0 - fx) * fy
                + idx(x0 + 1.0, y0 + 1.0) * fx * fy
        };
        let reach = n / 2;
        let profiles: Vec<Vec<f64>> = (0..DIRECTIONS)
            .map(|k| {
                let a = std::f64::consts::PI * k as f64 / DIRECTIONS as f64;
                (0..=reach)
                    .map(|r| at(r as f64 * a.cos(), r as f64 * a.sin()))
                    .collect()
            })
            .collect();
        let radial: Vec<f64> = (0..=reach)
            .map(|r| profiles.iter().map(|p| p[r]).sum::<f64>() / DIRECTIONS as f64)
            .collect();
        Self {
            size: n,
            lines: profiles.iter().map(|p| first_peak(p, false)).collect(),
            courses: profiles.iter().map(|p| first_peak(p, true)).collect(),
            radial: first_peak(&radial, false),
            scale: super::arrangement::feature_frequency(v, n),
            pieces: super::pieces::pieces(v, n),
        }
    }

    /// The periods of a rendered pattern.
    pub fn of_field(field: &[f32], n: usize) -> Self {
        let v: Vec<f64> = field.iter().map(|&x| f64::from(x)).collect();
        Self::of_values(&v, n)
    }

    /// The strongest direction's index and its peak.
    pub fn strongest(&self) -> (usize, Peak) {
        let mut best = (0, self.lines[0]);
        for (k, p) in self.lines.iter().enumerate() {
            if p.strength > best.1.strength {
                best = (k, *p);
            }
        }
        best
    }

    /// The direction across parallel lines: among the directions with a
    /// period nearly as strong as the strongest, the one of shortest period
    /// (along any other direction the same lines repeat more slowly).
    pub fn across(&self) -> Option<(f64, Peak)> {
        across_of(&self.lines, |_| 0.0)
    }

    /// The direction across courses (rows of bricks, boards), read from
    /// [`Self::courses`] for the seeds: among the directions with a period
    /// nearly as strong as the strongest, the one whose period the most
    /// directions bear out ([`support`]), the shortest among equals.
    pub fn courses_across(&self) -> Option<(f64, Peak)> {
        across_of(&self.courses, |k| support(&self.courses, k))
    }

    /// The course peak of the direction nearest `degrees`.
    pub fn course_along(&self, degrees: f64) -> Peak {
        self.courses[nearest(degrees)]
    }

    /// The peak of the direction nearest `degrees`.
    pub fn along(&self, degrees: f64) -> Peak {
        self.lines[nearest(degrees)]
    }

    /// The structure term: how differently two textures repeat, direction
    /// by direction. Each side's peak strengths are taken relative to its
    /// strongest (how anisotropic it is, not how sharp: a photo repeats
    /// less cleanly than a render); the term is the mean difference of
    /// those, plus, where both repeat, the log ratio of their periods
    /// weighted by the weaker. 0 for the same periods; a pattern repeating
    /// in two directions against one repeating in one scores high.
    pub fn distance(&self, other: &Self) -> f64 {
        let scale = other.size as f64 / self.size.max(1) as f64;
        let n = self.lines.len().min(other.lines.len()).max(1) as f64;
        let top = |p: &Self| p.lines.iter().map(|x| x.strength).fold(0.0, f64::max);
        let (ta, tb) = (top(self), top(other));
        if ta == 0.0 || tb == 0.0 {
            return if ta == tb { 0.0 } else { 1.0 };
        }
        let mut s = 0.0;
        for (a, b) in self.lines.iter().zip(&other.lines) {
            let (sa, sb) = (a.strength / ta, b.strength / tb);
            s += (sa - sb).abs();
            let w = sa.min(sb);
            if w > 0.0 {
                s += w * (a.period * scale / b.period).ln().abs().min(1.0);
            }
        }
        s / n
    }
}

/// `base` with the parameters `s`'s layout names set from the periods
/// `per` (§3.2.1: a start placed by the target's structure, so a count is
/// read from the fundamental period rather than found by search); `None`
/// when the layout has none or the target shows no such period.
pub fn seeded(s: &Shader, base: &[f64], per: &Periodicity) -> Option<Vec<f64>> {
    let n = per.size as f64;
    let mut p = base.to_vec();
    let strong = |k: &Peak| k.strength >= 2.0 * PROMINENCE && k.period > 0.0;
    match s.layout {
        Layout::Free => return None,
        Layout::Rows {
            count,
            aspect,
            angle,
        } => {
            let (across, v) = match angle {
                Some(_) => per.courses_across()?,
                None => (90.0, per.course_along(90.0)),
            };
            if !strong(&v) {
                return None;
            }
            p[count] = n / v.period;
            if let Some(k) = angle {
                p[k] = across;
            }
            if let Some(a) = aspect {
                let h = per.course_along(across + 90.0);
                if h.strength >= PROMINENCE && h.period > 0.0 {
                    p[a] = h.period / v.period;
                }
            }
        }
        Layout::Lines { count, angle } => {
            let (a, k) = per.courses_across()?;
            p[count] = n / k.period;
            p[angle] = a;
        }
        Layout::Scatter { count } => {
            // The count whose render has the target's number of pieces
            // where the target's features stand apart, else its feature
            // frequency (what a count gives depends on the shader's other
            // parameters, so it is measured, not assumed).
            let size = per.size.clamp(8, 128);
            let scattered = per.pieces.separation >= SCATTERED && per.pieces.count > 0.0;
            let want = if scattered {
                per.pieces.count * (size as f64 / per.size as f64).powi(2)
            } else {
                per.scale
            };
            if want <= 0.0 {
                return None;
            }
            let spec = &s.params[count];
            let mut best = (f64::INFINITY, p[count]);
            let mut c = spec.min.ceil();
            while c <= spec.max {
                p[count] = c;
                let f = s.render_field(&p, size, size, size);
                let v: Vec<f64> = f.iter().map(|&x| f64::from(x)).collect();
                let got = if scattered {
                    super::pieces::pieces(&v, size).count
                } else {
                    super::arrangement::feature_frequency(&v, size)
                };
                let miss = (got / want).ln().abs();
                if got > 0.0 && miss < best.0 {
                    best = (miss, c);
                }
                c += 1.0;
            }
            p[count] = best.1;
        }
    }
    Some(s.legal(&p))
}

/// The direction index nearest `degrees`.
fn nearest(degrees: f64) -> usize {
    let k = (degrees / 180.0 * DIRECTIONS as f64).round() as i64;
    k.rem_euclid(DIRECTIONS as i64) as usize
}

/// Among the directions of `lines` whose peak is at least
/// [`ACROSS_SHARE`] of the strongest, the one of highest `score`, then
/// shortest period, then first; with its angle in degrees.
fn across_of(lines: &[Peak], score: impl Fn(usize) -> f64) -> Option<(f64, Peak)> {
    let top = lines.iter().map(|p| p.strength).fold(0.0, f64::max);
    if top < 2.0 * PROMINENCE {
        return None;
    }
    let (k, p, _) = lines
        .iter()
        .enumerate()
        .filter(|(_, p)| p.strength >= ACROSS_SHARE * top)
        .map(|(k, p)| (k, p, score(k)))
        .max_by(|a, b| {
            a.2.total_cmp(&b.2)
                .then(b.1.period.total_cmp(&a.1.period))
                .then(b.0.cmp(&a.0))
        })?;
    Some((180.0 * k as f64 / lines.len() as f64, *p))
}

/// How many directions bear out direction `k`'s period as lines across
/// it, weighted by their strength: lines of period P across direction k
/// cross a direction δ away every P / cos δ. Courses of bricks hold over
/// a wide fan of directions; the grain within one brick, a few.
fn support(lines: &[Peak], k: usize) -> f64 {
    let pk = lines[k].period;
    if pk <= 0.0 {
        return 0.0;
    }
    let n = lines.len();
    let step = 180.0 / n as f64;
    lines
        .iter()
        .enumerate()
        .filter(|(j, q)| {
            let d = (*j as i64 - k as i64).rem_euclid(n as i64) as usize;
            let delta = d.min(n - d) as f64 * step;
            q.period > 0.0
                && delta <= SUPPORT_FAN
                && (q.period * delta.to_radians().cos() / pk).ln().abs() <= SUPPORT_TOLERANCE
        })
        .map(|(_, q)| q.strength)
        .sum()
}

/// Whether the peak at lag `r` repeats: where twice the lag is in reach,
/// the correlation there (±1) rises above the one at one and a half times
/// it. A period's second repeat comes back; the broad hump of a texture's
/// grain within its tiles (the striation of a stone brick) only decays.
fn repeats(p: &[f64], r: usize) -> bool {
    let twice = 2 * r;
    if twice + 1 >= p.len() {
        return true;
    }
    let back = p[twice - 1].max(p[twice]).max(p[twice + 1]);
    back > p[(3 * r).div_ceil(2)]
}

/// The first clear peak of a correlation profile (index = lag); with
/// `repeating`, the first that [`repeats`].
fn first_peak(p: &[f64], repeating: bool) -> Peak {
    let none = Peak {
        period: 0.0,
        strength: 0.0,
    };
    let start = MIN_PERIOD.ceil() as usize;
    if p.len() < start + 2 {
        return none;
    }
    let mut low = f64::INFINITY;
    let mut peaks: Vec<(usize, f64)> = Vec::new();
    for r in 1..p.len() - 1 {
        low = low.min(p[r]);
        if r >= start && p[r] >= p[r - 1] && p[r] > p[r + 1] {
            let rise = p[r] - low;
            if rise >= PROMINENCE && p[r] > 0.0 && (!repeating || repeats(p, r)) {
                peaks.push((r, rise));
            }
        }
    }
    let top = peaks.iter().map(|x| x.1).fold(0.0, f64::max);
    let Some(&(r, rise)) = peaks.iter().find(|x| x.1 >= FIRST_PEAK_SHARE * top) else {
        return none;
    };
    // The peak's lag refined by the parabola through its neighbours.
    let (a, b, c) = (p[r - 1], p[r], p[r + 1]);
    let den = a - 2.0 * b + c;
    let shift = if den.abs() > 1e-12 {
        (0.5 * (a - c) / den).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    // ...and its height by the parabola's vertex: a peak narrower than a
    // few pixels (a fine grid's) falls between the samples.
    let top = if den < -1e-12 {
        b - 0.125 * (a - c) * (a - c) / den
    } else {
        b
    };
    Peak {
        period: r as f64 + shift,
        strength: rise + (top - b),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::by_name;

    #[test]
    fn stripes_give_their_period_and_direction_not_a_harmonic() {
        let s = by_name("stripes").unwrap();
        let n = 128;
        // 7 stripes per unit across 30°: period 128/7 ≈ 18.3 px.
        let f = s.render_field(&[7.0, 30.0, 0.3, 0.1], n, n, n);
        let p = Periodicity::of_field(&f, n);
        let (angle, peak) = p.across().expect("stripes repeat");
        assert!((angle - 30.0).abs() <= 5.0, "{angle}");
        let count = n as f64 / peak.period;
        assert!((count - 7.0).abs() < 0.5, "{count}");
    }

    #[test]
    fn planks_repeat_in_one_direction_and_bricks_in_two() {
        let n = 128;
        let planks = by_name("planks").unwrap();
        let bricks = by_name("bricks").unwrap();
        let pl =
            Periodicity::of_field(&planks.render_field(&[8.0, 0.0, 6.0, 0.1, 0.2], n, n, n), n);
        let br = Periodicity::of_field(
            &bricks.render_field(&[8.0, 1.0, 0.1, 0.0, 0.1, 90.0], n, n, n),
            n,
        );
        // Planks across x (0°) repeat every 16 px; along y hardly at all.
        assert!(
            (pl.along(0.0).period - 16.0).abs() < 1.0,
            "{:?}",
            pl.along(0.0)
        );
        assert!(pl.along(90.0).strength < 0.5 * pl.along(0.0).strength);
        // Square stack-bond bricks repeat both ways.
        assert!(
            (br.along(90.0).period - 16.0).abs() < 1.0,
            "{:?}",
            br.along(90.0)
        );
        assert!(
            (br.along(0.0).period - 16.0).abs() < 1.0,
            "{:?}",
            br.along(0.0)
        );
        // So planks sit closer to planks turned slightly than to the grid.
        let pl2 = Periodicity::of_field(
            &planks.render_field(&[8.0, 3.0, 5.0, 0.15, 0.3], n, n, n),
            n,
        );
        assert!(
            pl.distance(&pl2) < pl.distance(&br),
            "{} {}",
            pl.distance(&pl2),
            pl.distance(&br)
        );
    }

    #[test]
    fn scattered_features_seed_their_count() {
        let n = 128;
        for (name, truth) in [
            ("cells", &[9.0, 0.8, 0.7, 0.25][..]),
            ("spots", &[6.0, 0.3, 0.2][..]),
        ] {
            let s = by_name(name).unwrap();
            let f = s.render_field(truth, n, n, n);
            let per = Periodicity::of_field(&f, n);
            let mut base = truth.to_vec();
            base[0] = 3.0;
            let p = seeded(s, &base, &per).expect("a feature frequency");
            assert!((p[0] - truth[0]).abs() <= 1.0, "{name}: {p:?}");
        }
    }

    #[test]
    fn courses_skip_a_grain_hump_that_does_not_repeat() {
        // A correlation profile with the broad hump of a grain at lag 6
        // that only decays, over courses every 24 px.
        let p: Vec<f64> = (0..64)
            .map(|r| {
                let r = r as f64;
                0.2 * (std::f64::consts::TAU * r / 24.0).cos()
                    + 0.6 * (-((r - 6.0) / 2.0).powi(2)).exp()
                    + 0.6 * (-r / 1.5).exp()
            })
            .collect();
        assert_eq!(first_peak(&p, false).period.round(), 6.0);
        assert!(!repeats(&p, 6));
        assert_eq!(first_peak(&p, true).period.round(), 24.0);
        // A true period repeats and is kept either way.
        let q: Vec<f64> = (0..64)
            .map(|r| 0.8 * (std::f64::consts::TAU * r as f64 / 8.0).cos())
            .collect();
        assert!(repeats(&q, 8));
        assert_eq!(first_peak(&q, true).period, first_peak(&q, false).period);
    }

    #[test]
    fn the_course_direction_is_the_one_a_fan_of_directions_bears_out() {
        // Courses 16 px apart across 90° cross every direction δ away every
        // 16 / cos δ px; a short grain along 0° holds in that direction only.
        let step = 180.0 / DIRECTIONS as f64;
        let lines: Vec<Peak> = (0..DIRECTIONS)
            .map(|k| {
                let delta = (k as f64 * step - 90.0).abs();
                if k == 0 {
                    Peak {
                        period: 6.0,
                        strength: 0.6,
                    }
                } else if delta <= 60.0 {
                    Peak {
                        period: 16.0 / delta.to_radians().cos(),
                        strength: 0.5,
                    }
                } else {
                    Peak {
                        period: 30.0,
                        strength: 0.1,
                    }
                }
            })
            .collect();
        let (shortest, _) = across_of(&lines, |_| 0.0).unwrap();
        assert_eq!(shortest, 0.0);
        let (angle, peak) = across_of(&lines, |k| support(&lines, k)).unwrap();
        assert_eq!(angle, 90.0);
        assert_eq!(peak.period, 16.0);
        assert!(support(&lines, 0) < support(&lines, DIRECTIONS / 2));
    }

    #[test]
    fn flat_and_tiny_images_have_no_period_and_do_not_panic() {
        let p = Periodicity::of_values(&vec![3.0; 16 * 16], 16);
        assert!(p.lines.iter().all(|x| x.strength == 0.0));
        assert!(p.across().is_none());
        let p = Periodicity::of_values(&[1.0, 2.0, 3.0, 4.0], 2);
        assert_eq!(p.radial.strength, 0.0);
        assert_eq!(p.distance(&p), 0.0);
    }
}
