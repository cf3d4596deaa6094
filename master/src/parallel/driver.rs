//! The one level loop of the synthesis on coordinates, in 2-D (a plane of
//! pixels, Manke–Wünsche §3–4) and in 3-D (a volume of voxels, §5): per
//! level, each exemplar's level and k-coherence candidate sets, then the
//! coordinates started or upsampled and jittered, then the correction passes.
//! A [`Lattice`] is what differs between the plane and the volume.

use anyhow::{ensure, Result};
use rayon::prelude::*;

use super::appearance::Pca;
use super::cache::CandidateCache;
use super::candidates::{Candidates, SetsOf, Spacing};
use super::exemplar::ExemplarLevel;
use super::neighbourhood::Neighbourhood;
use crate::imaging::ColorImage;
use crate::progress::Progress;
use crate::search::SearchBackend;

/// Settings of a synthesis on coordinates.
#[derive(Clone, Debug)]
pub struct ParallelSettings {
    pub neighbourhood: Neighbourhood,
    /// Jitter strength `r_i` per level, coarsest first (the last value
    /// repeats).
    pub jitter: Vec<f64>,
    /// The coarsest level's coordinates.
    pub start: Start,
    /// Correction passes per level (each of 4 sub-passes).
    pub passes: usize,
    /// Correction passes of the finest level, where they differ from
    /// `passes` (none: `passes`). The finest level's passes refine pixels
    /// whose layout the coarser levels have decided, so there more passes
    /// sharpen without growing one offset over the output.
    pub fine_passes: Option<usize>,
    /// Correct every level, as the paper does. Off by default: a level whose
    /// neighbourhood spans [`MAX_SPAN`] of the exemplar or more is only
    /// jittered ([`corrected`]).
    pub every_level: bool,
    /// The coarse levels' own correction (every level but the finest;
    /// ARCHITECTURE §10); none: every level as the finest.
    pub coarse: Option<CoarseLevels>,
    /// k of the k-coherence candidate sets.
    pub k: usize,
    /// Coherence weight `c` of the correction's choice (ARCHITECTURE §10):
    /// a candidate continued coherently by `v` of the pixel's 3×3 neighbours
    /// (itself included) has its distance scaled by `1 + c·(1 − v/9)`, so a
    /// candidate that breaks the neighbours' agreement must be clearly
    /// better. 0 is the paper's plain eq. 3. Solids honour it too, but
    /// `texsyn solid` keeps 0: on 64³ walnut and pink marble a weight of 10
    /// brought the centre slices' S_L nearer the 2-D synthesis but raised
    /// their contrast past 1.2× and their Nyquist energy past the
    /// exemplar's (ARCHITECTURE §11).
    pub coherence: f32,
    /// The copy guard (ARCHITECTURE §10): before each correction sub-pass
    /// of a plane, the offsets (coordinate minus `h` times the position,
    /// modulo the exemplar) that more than this share of the level's pixels
    /// hold are closed, so no pixel moves into one and no coherent copy of
    /// the exemplar grows past it; pixels already there may stay. None: no
    /// guard (the paper's). Solids take none.
    pub copy_guard: Option<f32>,
    /// Strength of the histogram matching of the blend before each
    /// correction sub-pass, 0 to 1 ([`super::histogram`]; 0: the paper's
    /// plain method).
    pub histogram: f32,
    pub seed: u64,
    /// The memory the run may take: a larger output is refused before any work.
    pub budget: crate::budget::Budget,
    /// How a morph's output colour is drawn from its exemplars.
    pub colour: MorphColour,
    /// Lattice phase of a plane (ARCHITECTURE §10): every exemplar's grid,
    /// whose phase each pixel's offset keeps within
    /// [`crate::lattice::PHASE_TOLERANCE`] (`None`: off). Solids take
    /// their own (`SolidSettings::lattice`).
    pub lattice: Option<crate::lattice::Lattice>,
    /// Where the candidate sets are kept between runs (none: searched
    /// every run).
    pub cache: Option<CandidateCache>,
}

/// How the levels above the finest are corrected, where they differ from
/// it (not in the paper; ARCHITECTURE §10). The coarse levels lay out what
/// the finest refines, and a reduced neighbourhood's few averaged points
/// cannot see a brick course or a tile's edge there; those levels are a
/// quarter of the finest's pixels and less, so a full neighbourhood costs
/// little where it decides the layout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoarseLevels {
    pub neighbourhood: Neighbourhood,
    /// Correction passes per coarse level.
    pub passes: usize,
    /// Coherence weight of the coarse levels' choice
    /// ([`ParallelSettings::coherence`]).
    pub coherence: f32,
}

/// What one level is corrected with: its neighbourhood's points, passes and
/// coherence weight ([`ParallelSettings::recipe_at`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Recipe {
    pub points: Vec<Vec<[i32; 2]>>,
    pub passes: usize,
    pub coherence: f32,
}

/// How a morph's output colour is drawn from its exemplars (ARCHITECTURE
/// §10). One exemplar gives the same colour either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MorphColour {
    /// Per pixel the colour of one exemplar, the one whose neighbourhood at
    /// its coordinate fits the blended neighbourhood best for its weight:
    /// where both exemplars have weight, each region shows one exemplar's
    /// features whole instead of both at half strength.
    #[default]
    Best,
    /// The weighted sum `Σ Wʲ·Eʲ(Sʲ)` (Manke–Wünsche eq. 2 in colour): a
    /// double exposure where the weights are even.
    Weighted,
}

impl ParallelSettings {
    /// The defaults the command line gives neighbourhood `n` in a synthesis
    /// (`morph` false) or a morph: [`default_passes`] and
    /// [`default_coherence`] on top of [`ParallelSettings::default`], which
    /// keeps the paper's 2 passes and plain choice.
    pub fn defaults_for(n: Neighbourhood, morph: bool) -> Self {
        Self {
            neighbourhood: n,
            passes: default_passes(n, morph),
            fine_passes: default_fine_passes(n, morph),
            coherence: default_coherence(n),
            copy_guard: default_copy_guard(morph),
            jitter: default_jitter(n, morph).to_vec(),
            k: default_k(n, morph),
            coarse: default_coarse(n, morph),
            ..Self::default()
        }
    }
}

impl ParallelSettings {
    /// The correction passes of `level` (0 the coarsest) of `levels`:
    /// [`Self::fine_passes`] at the finest, [`Self::passes`] elsewhere.
    pub fn passes_at(&self, level: usize, levels: usize) -> usize {
        match self.fine_passes {
            Some(p) if level + 1 == levels => p,
            _ => self.passes,
        }
    }

    /// The neighbourhood, passes and coherence weight of `level` (0 the
    /// coarsest) of `levels`: [`Self::coarse`]'s above the finest level
    /// where it is set, else the main settings ([`Self::passes_at`]).
    pub fn recipe_at(&self, level: usize, levels: usize) -> Recipe {
        match self.coarse {
            Some(c) if level + 1 < levels => Recipe {
                points: c.neighbourhood.points(),
                passes: c.passes,
                coherence: c.coherence,
            },
            _ => Recipe {
                points: self.neighbourhood.points(),
                passes: self.passes_at(level, levels),
                coherence: self.coherence,
            },
        }
    }

    /// The most points any level's neighbourhood has (what a level's
    /// exemplar vectors take in memory).
    pub fn most_points(&self) -> usize {
        let main = self.neighbourhood.points().len();
        self.coarse
            .map_or(main, |c| main.max(c.neighbourhood.points().len()))
    }
}

impl Default for ParallelSettings {
    fn default() -> Self {
        Self {
            neighbourhood: Neighbourhood::Reduced,
            jitter: DEFAULT_JITTER.to_vec(),
            start: Start::Random,
            passes: 2,
            fine_passes: None,
            every_level: false,
            k: 4,
            coarse: None,
            coherence: 0.0,
            copy_guard: None,
            histogram: DEFAULT_HISTOGRAM,
            seed: 1,
            budget: crate::budget::Budget::default(),
            colour: MorphColour::default(),
            cache: None,
            lattice: None,
        }
    }
}

/// Default jitter strengths per level, coarsest first (the last repeats):
/// strong where the layout is decided, so no neighbourhood settles into a
/// copy of the exemplar, and light at the fine levels, whose corrections
/// only refine. The paper's single value is `--jitter 0.4`.
pub const DEFAULT_JITTER: [f64; 4] = [1.0, 0.8, 0.6, 0.4];

/// The jitter the command line gives `n` unless told otherwise:
/// [`DEFAULT_JITTER`], and for 5×5 a stronger jitter at the fine levels
/// (0.7, then 0.6), which its fourth correction pass needs: with 4 passes
/// and the default jitter one offset grew over 0.108 of `cracked_color_144`
/// at 2× its side; with this one the largest on the 22 samples up to 256²
/// is 0.078. For `reduced` in a synthesis a lighter one at the fine levels
/// (0.5, then 0.3) under [`default_copy_guard`]: on the same samples its
/// fidelity ratio to the block method came within 1.3 on 7 (5 with the
/// default; unguarded also 7, but one offset over 0.115 of an output),
/// largest `copy_share` 0.069. `half` takes the same in a synthesis (with
/// its 3×3 centre: 10 of 22, from 8 with the default jitter, 4 passes and
/// no guard; 1 with the earlier one-pixel centre).
pub fn default_jitter(n: Neighbourhood, morph: bool) -> &'static [f64] {
    match n {
        Neighbourhood::Full(5) => &[1.0, 0.8, 0.7, 0.6],
        Neighbourhood::Reduced | Neighbourhood::Half if !morph => &[1.0, 0.8, 0.5, 0.3],
        _ => &DEFAULT_JITTER,
    }
}

/// Default strength of the histogram matching: full (ARCHITECTURE §10–11).
pub const DEFAULT_HISTOGRAM: f32 = 1.0;

/// Correction passes per level that the command line gives `n` unless told
/// otherwise. For 7×7 5, whose corrections had not settled after two: on 8
/// samples at 2× their side a third 7×7 pass lowered the patch fidelity
/// ratio to the block method on every one (facade 1.81 → 1.67, tiles
/// 1.47 → 1.37, leaves 1.34 → 1.27, brick 96 1.32 → 1.25) for about 1.3×
/// the time; with [`default_k`]'s 8 candidates, on the 22 samples up to
/// 256² it came within 1.3 on 17 with 4 passes, 19 with 5 and 18 with 6
/// (largest `copy_share` 0.063, 0.080, 0.096). For 5×5 7 in a synthesis,
/// under [`default_copy_guard`] (with [`default_jitter`]): against the
/// block method of 2026-12-03, on the 22 samples up to 256² at 2× their
/// side its fidelity ratio was within 1.3 on 12 with 4 passes, 14 with 5,
/// and unguarded 17 with 7 but one offset over 0.12 of an output; guarded,
/// 17 with 7 or 8 (largest `copy_share` 0.054, 0.057), 18 with 9 (median
/// ratio 1.178, 0.053; 10 gave 17, 12 gave 18 with S_L on 19); 4 in a
/// morph. For `reduced` and `half`, with their coherence
/// weight ([`default_coherence`]), 4 in a synthesis: on the 22 samples up
/// to 256² at 2× their side the median fidelity ratio
/// to the block method fell from 1.50 (2 passes) to 1.37 (`reduced`); a
/// morph (`morph`) keeps the paper's 2, which keeps a cached 512² morph
/// under 2 and 3 s. `half` takes 8 in a synthesis, with 8 candidates
/// ([`default_k`]).
pub fn default_passes(n: Neighbourhood, morph: bool) -> usize {
    match n {
        Neighbourhood::Full(7) => 5,
        Neighbourhood::Full(5) if !morph => 9,
        Neighbourhood::Full(_) => 4,
        Neighbourhood::Reduced | Neighbourhood::Half if morph => 2,
        Neighbourhood::Half => 8,
        Neighbourhood::Reduced => 4,
    }
}

/// The finest level's correction passes that the command line gives `n`
/// in a synthesis unless told otherwise ([`ParallelSettings::fine_passes`]):
/// 8 for `reduced` and `half`, none (as the other levels) elsewhere. On the 22 samples
/// up to 256² at 2× their side `reduced`'s fidelity ratio to the block
/// method came within 1.3 on 5 (3 with 4 passes everywhere; 12 gained
/// nothing more), largest `copy_share` 0.080; `half` stayed at 1. For 5×5
/// 8 at the finest and 4 elsewhere took it from 12 to 16 (copy up to
/// 0.085), but 7 everywhere under [`default_copy_guard`] to 17 (0.054).
/// `half` (with its 3×3 centre) takes `reduced`'s finest passes, guard and
/// jitter: 10 of 22, largest `copy_share` 0.067 (8 with 4 passes, the
/// default jitter and no guard, `copy_share` up to 0.117). A morph keeps
/// its passes.
pub fn default_fine_passes(n: Neighbourhood, morph: bool) -> Option<usize> {
    match n {
        Neighbourhood::Reduced | Neighbourhood::Half if !morph => Some(8),
        _ => None,
    }
}

/// The copy guard ([`ParallelSettings::copy_guard`]) the command line gives
/// a synthesis unless told otherwise: 0.08 for every neighbourhood; none in
/// a morph.
/// 5×5's 7 to 9 passes ([`default_passes`]) grow one offset over 0.12 of an
/// output without it (stone33); with it and 7 passes, on the 22 samples up
/// to 256² at 2× their side, the largest `copy_share` is 0.054 and the
/// fidelity ratio to the block method is within 1.3 on 17 (median 1.205;
/// with 9, 18, 1.178 and 0.053; 16 and 1.264 with
/// 4 passes and 8 at the finest, unguarded; 16 with a guard of 0.09). At
/// 0.05 it held copies to 0.042 but gave 13: pieces of copy are where the
/// output is nearest the exemplar. `reduced` and `half` take it with their
/// lighter jitter ([`default_jitter`]). 7×7 without it grew one offset over
/// 0.106 of a 1024² output from the 512² grass, and over 0.12 of the
/// facade's and the coloured tiles' under lattice phase; with it 0.069,
/// 0.050 and 0.065, and on the 22 samples the same counts within 1.3× of the
/// block method (fidelity 20, S_L 21; largest `copy_share` 0.080 → 0.065).
pub fn default_copy_guard(morph: bool) -> Option<f32> {
    (!morph).then_some(0.08)
}

/// The k of the candidate sets ([`ParallelSettings::k`]) that the command
/// line gives `n` unless told otherwise. 8 for 7×7, whose 49 points tell
/// candidates apart finely enough that more of them pay: on the 22 samples
/// up to 256² at 2× their side (4 passes) its patch fidelity came within
/// 1.3× of the block method's on 17 (16 with k = 4, brick 256 1.38 → 1.19)
/// for about 1.5× the time, and with [`default_passes`]' 5 on 19. 8 for
/// `half` in a synthesis, with 8 passes at every level: its nine points
/// tell the larger set apart too, and the passes settle what the larger
/// set offers (on the same 22 samples, within 1.3× on 15 against 10 with
/// `k` = 4 and 4 passes, median ratio 1.306 → 1.242, S_L within 1.3× on 20
/// as before, largest `copy_share` 0.066, for about 1.3× the time; `k` = 8
/// alone gave 13, 6 passes 15 at a median of 1.270, 10 passes 15 at
/// 1.229; `k` = 12 or 16 with 4 passes 10 and 11). 4, the paper's order,
/// for the others and for a morph (whose cached 512² run stays within its
/// time), where 8 did not help (`reduced` 6 of 22 against 7, 7 with 8
/// passes; 5×5 11 against 12).
pub fn default_k(n: Neighbourhood, morph: bool) -> usize {
    match n {
        Neighbourhood::Full(7) => 8,
        Neighbourhood::Half if !morph => 8,
        _ => 4,
    }
}

/// The coherence weight ([`ParallelSettings::coherence`]) that the command
/// line gives `n` unless told otherwise: 10 for `reduced` and `half`, whose
/// four or nine averaged points cannot tell a pixel's exact alignment, so
/// left alone their corrections kept only 68% of neighbour pairs coherent
/// (walnut 128 → 256²; 87% with the weight, 92% for 7×7 without it); 0 for
/// 5×5 and 7×7, where the weight made fidelity and S_L worse.
pub fn default_coherence(n: Neighbourhood) -> f32 {
    match n {
        Neighbourhood::Full(_) => 0.0,
        Neighbourhood::Reduced | Neighbourhood::Half => 10.0,
    }
}

/// The coarse levels' default correction (ARCHITECTURE §10): in `synth`,
/// the reduced and half neighbourhoods correct every level above the finest
/// with the full 7×7 neighbourhood, 16 passes (40 for reduced,
/// [`REDUCED_COARSE_PASSES`]) and the plain choice. On the
/// 22 samples up to 256² at 2× their side it took the patch fidelity
/// within 1.3× of the block method's from 15 to 19 (`half`) and from 7 to
/// 16 (`reduced`) at seed 1 (ARCHITECTURE §10 for other seeds), for about
/// 1.7× the time. 5×5 takes them too (16 passes): on the 22 it gave 20
/// against 19 (S_L on 21 against 22), and on the four samples of about 512²
/// at 2× all four within 1.3 against none (brick 1.42 → 1.29). A morph
/// keeps one neighbourhood (its cached sets are meant to make it a matter
/// of seconds), and so does 7×7.
pub fn default_coarse(n: Neighbourhood, morph: bool) -> Option<CoarseLevels> {
    match n {
        Neighbourhood::Reduced | Neighbourhood::Half | Neighbourhood::Full(5) if !morph => {
            Some(CoarseLevels {
                neighbourhood: Neighbourhood::Full(7),
                passes: if n == Neighbourhood::Reduced {
                    REDUCED_COARSE_PASSES
                } else {
                    COARSE_PASSES
                },
                coherence: default_coherence(Neighbourhood::Full(7)),
            })
        }
        _ => None,
    }
}

/// Correction passes of the coarse levels by default ([`default_coarse`]):
/// 8, 12 and 16 gave 16, 17 and 19 of 22 for `half` (7×7, plain choice,
/// seed 1).
pub const COARSE_PASSES: usize = 16;

/// Correction passes of the coarse levels under the reduced neighbourhood
/// ([`default_coarse`]): its four averaged points at the finest level keep
/// less of the layout than half's nine, so more passes above pay. At seeds
/// 1, 2 and 3, 40 passes gave 18, 19 and 17 of 22 within 1.3× the block
/// method's fidelity against 16's 16, 19 and 17, the mean ratio lower at
/// each (1.215 → 1.189 at seed 1), for about 1.6× the time (ARCHITECTURE
/// §10); 32, 48 and 64 gave 17, 18 and 17 at seed 1.
pub const REDUCED_COARSE_PASSES: usize = 40;

/// The share of the exemplar's smaller side that a neighbourhood must span
/// less than for its level to be corrected by default ([`corrected`]).
pub const MAX_SPAN: f64 = 0.5;

/// Whether the level of step `h` is corrected. A neighbourhood whose points
/// span [`MAX_SPAN`] of the smallest exemplar side or more sees most of the
/// exemplar, and the one neighbourhood that then matches everywhere is
/// the exemplar itself: correcting there lets one coherent offset take over
/// the output (a 7×7 neighbourhood from the coarsest level made tiled copies,
/// `copy_share` up to 1.0). Such a level keeps its start or its upsampled
/// parent, jittered (§4.2), so the coarse layout stays random; the finest
/// level is always corrected. `every_level` is the paper's choice (§4: every
/// level corrected).
pub fn corrected(points: &[Vec<[i32; 2]>], h: usize, smallest: usize, every_level: bool) -> bool {
    let reach = points
        .iter()
        .flatten()
        .map(|o| o[0].unsigned_abs().max(o[1].unsigned_abs()) as usize)
        .max()
        .unwrap_or(0);
    every_level || h == 1 || ((2 * reach * h) as f64) < MAX_SPAN * smallest as f64
}

/// How the coarsest level's coordinates start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// §4.1: `S(P) = P mod s_e`, the exemplar tiled, every offset 0.
    Tiled,
    /// Each pixel a hashed exemplar pixel: every offset equally likely.
    Random,
}

impl Start {
    /// Parses `tiled` or `random`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "tiled" | "tile" => Ok(Self::Tiled),
            "random" => Ok(Self::Random),
            _ => anyhow::bail!(
                "--start '{s}' is not one of random (the default) or tiled (the paper's §4.1)"
            ),
        }
    }
}

/// Levels of a synthesis from `exemplars`: the coarsest step is the largest
/// power of two up to a quarter of the smallest exemplar side.
pub(super) fn level_count(exemplars: &[&ColorImage]) -> usize {
    let smallest = smallest_side(exemplars);
    (usize::BITS - (smallest / 4).max(1).leading_zeros()) as usize
}

/// The smallest side of any exemplar.
fn smallest_side(exemplars: &[&ColorImage]) -> usize {
    exemplars
        .iter()
        .map(|e| e.width.min(e.height))
        .min()
        .unwrap_or(8)
}

/// Exemplar j's jitter seed (exemplar 0 keeps `seed`, so a one-exemplar
/// morph is the plain synthesis).
pub(super) fn exemplar_seed(seed: u64, j: usize) -> u64 {
    seed.wrapping_add((j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
}

/// Jitter strength of `level` (coarsest first; the last value repeats).
pub(super) fn jitter_at(s: &ParallelSettings, level: usize) -> f64 {
    *s.jitter.get(level).or(s.jitter.last()).unwrap_or(&0.0)
}

/// Checks an exemplar's size: at least 8×8 (one level of 5×5 windows) and at
/// most 65535 per side (what a coordinate map holds); `what` names it.
pub(super) fn check_exemplar(e: &ColorImage, what: &str) -> Result<()> {
    ensure!(
        e.width >= 8 && e.height >= 8,
        "{what} is {}×{}; an exemplar must be at least 8×8",
        e.width,
        e.height
    );
    ensure!(
        e.width <= 65535 && e.height <= 65535,
        "{what} is wider or taller than 65535 pixels, which a coordinate map cannot hold"
    );
    Ok(())
}

/// The exemplars at one level: each at the level's blur, with its
/// k-coherence candidate sets (`k` and a table of `k` per pixel).
pub(super) struct LevelExemplars {
    pub ex: Vec<ExemplarLevel>,
    pub cands: Vec<(usize, Vec<[u32; 2]>)>,
    /// Grid stride of the first exemplar's candidate sets (0: none searched).
    pub stride: usize,
}

impl LevelExemplars {
    /// Builds the level of step `h` of every exemplar and, with `k`, searches
    /// its candidate sets through `backend` (exemplar `e` of `level` is the
    /// backend's level `level · exemplars + e`: a worker keeps one level per
    /// number), or reads them from `cache` when an earlier run stored them.
    /// Without `k` (a level not corrected) the sets are empty.
    #[allow(clippy::too_many_arguments)]
    fn build(
        exemplars: &[&ColorImage],
        h: usize,
        pca: &Pca,
        points: &[Vec<[i32; 2]>],
        k: Option<usize>,
        level: usize,
        cache: Option<&CandidateCache>,
        backend: &mut dyn SearchBackend,
        progress: &dyn Progress,
    ) -> Result<Self> {
        let mut ex = Vec::with_capacity(exemplars.len());
        let mut cands = Vec::with_capacity(exemplars.len());
        let mut stride = 0;
        for (e, img) in exemplars.iter().enumerate() {
            let started = std::time::Instant::now();
            let level_ex = ExemplarLevel::build(img, h, pca, points);
            let analysed = started.elapsed().as_secs_f64();
            let Some(k) = k else {
                ex.push(level_ex);
                cands.push((1, Vec::new()));
                continue;
            };
            let of = SetsOf {
                appearance: &level_ex.appearance,
                size: (level_ex.width, level_ex.height),
                dims: level_ex.dims,
                spacing: Spacing::of_step(h),
                k,
            };
            let mut search =
                || Candidates::search(&of, level * exemplars.len() + e, backend, progress);
            let c = match cache {
                Some(cache) => {
                    let (c, hit) = cache.get_or_search(&of, search)?;
                    tracing::debug!(level, exemplar = e, hit, "candidate cache");
                    c
                }
                None => search()?,
            };
            tracing::debug!(
                level,
                exemplar = e,
                analysis = analysed,
                sets = started.elapsed().as_secs_f64() - analysed,
                "exemplar level timings (s)"
            );
            if e == 0 {
                stride = c.stride();
            }
            ex.push(level_ex);
            cands.push((c.k(), c.table()));
        }
        Ok(Self { ex, cands, stride })
    }
}

/// What the level loop drives: a plane of pixels or a volume of voxels,
/// holding every exemplar's (or view's) coordinates.
pub(super) trait Lattice {
    /// Sub-passes of one correction pass (4 in a plane, 8 in a volume).
    const SUB_PASSES: usize;
    /// The coordinates of the level of step `h`: the start at the coarsest
    /// level, the previous level upsampled after it, then jittered with
    /// strength `r`.
    fn prepare(&mut self, level: usize, h: usize, r: f64);
    /// The level's correction: `passes` passes of [`Self::SUB_PASSES`]
    /// sub-passes against `ex` with the coherence weight `coherence`, one
    /// progress step per sub-pass.
    fn correct(
        &mut self,
        ex: &LevelExemplars,
        points: &[Vec<[i32; 2]>],
        passes: usize,
        coherence: f32,
        progress: &dyn Progress,
    );
}

/// Runs every level of `lattice` from `exemplars`, coarsest first, and
/// returns each level's candidate grid stride.
pub(super) fn run_levels<L: Lattice>(
    lattice: &mut L,
    exemplars: &[&ColorImage],
    pca: &Pca,
    s: &ParallelSettings,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Vec<usize>> {
    let levels = level_count(exemplars);
    let mut strides = Vec::with_capacity(levels);
    for level in 0..levels {
        let h = 1usize << (levels - 1 - level);
        let Recipe {
            points,
            passes,
            coherence,
        } = s.recipe_at(level, levels);
        let passes = if corrected(&points, h, smallest_side(exemplars), s.every_level) {
            passes
        } else {
            0
        };
        let t = std::time::Instant::now();
        // A level without correction reads no candidate: none are searched.
        let ex = LevelExemplars::build(
            exemplars,
            h,
            pca,
            &points,
            (passes > 0).then_some(s.k),
            level,
            s.cache.as_ref(),
            backend,
            progress,
        )?;
        strides.push(ex.stride);
        let t_exemplars = t.elapsed().as_secs_f64();
        lattice.prepare(level, h, jitter_at(s, level));
        let t = std::time::Instant::now();
        progress.start(
            &format!("level {}/{levels}", level + 1),
            (passes * L::SUB_PASSES) as u64,
            "sub-passes",
        );
        lattice.correct(&ex, &points, passes, coherence, progress);
        progress.finish();
        tracing::debug!(
            level,
            passes,
            exemplar_levels_and_candidates = t_exemplars,
            correction = t.elapsed().as_secs_f64(),
            "level timings (s)"
        );
    }
    Ok(strides)
}

/// The output colour `Σ Wʲ·Eʲ(Sʲ)` of `n` pixels or voxels from `m`
/// exemplars (or views, or replayed maps), rounded to bytes: `term(i, j)` is
/// exemplar `j`'s weight and colour at `i`. `channels` is 3, or 1 for the
/// first channel only.
pub fn blend(
    n: usize,
    m: usize,
    channels: usize,
    term: impl Fn(usize, usize) -> (f32, [u8; 3]) + Sync,
) -> Vec<u8> {
    let mut out = vec![0u8; n * channels];
    out.par_chunks_mut(channels)
        .enumerate()
        .for_each(|(i, px)| {
            let mut acc = [0.0f32; 3];
            for j in 0..m {
                let (w, p) = term(i, j);
                for (a, v) in acc.iter_mut().zip(p) {
                    *a += w * f32::from(v);
                }
            }
            for (o, a) in px.iter_mut().zip(acc) {
                *o = a.round().clamp(0.0, 255.0) as u8;
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_whose_neighbourhood_spans_over_half_the_exemplar_are_not_corrected() {
        let seven = Neighbourhood::Full(7).points();
        let reduced = Neighbourhood::Reduced.points();
        // 7×7 reaches 3 steps each way: 6h against half of 128.
        assert!(corrected(&seven, 8, 128, false));
        assert!(!corrected(&seven, 16, 128, false));
        assert!(corrected(&seven, 16, 128, true));
        // Reduced reaches one step: 2h, corrected below half the side only.
        assert!(corrected(&reduced, 16, 128, false));
        assert!(!corrected(&reduced, 32, 128, false));
        assert!(corrected(&reduced, 32, 129, false));
        // The finest level always is, however small the exemplar.
        assert!(corrected(&seven, 1, 8, false));
        assert!(!corrected(&seven, 2, 8, false));
    }

    #[test]
    fn coarse_levels_take_their_own_recipe_and_the_finest_the_main_one() {
        let s = ParallelSettings::defaults_for(Neighbourhood::Half, false);
        let coarse = s.coarse.expect("half in synth has coarse levels");
        assert_eq!(coarse.neighbourhood, Neighbourhood::Full(7));
        for level in 0..4 {
            let r = s.recipe_at(level, 5);
            assert_eq!(r.points, Neighbourhood::Full(7).points());
            assert_eq!((r.passes, r.coherence), (COARSE_PASSES, 0.0));
        }
        let finest = s.recipe_at(4, 5);
        assert_eq!(finest.points, Neighbourhood::Half.points());
        assert_eq!(finest.passes, s.passes_at(4, 5));
        assert_eq!(finest.coherence, default_coherence(Neighbourhood::Half));
        assert_eq!(s.most_points(), 49);
        // One level is the finest: no coarse level at all.
        assert_eq!(s.recipe_at(0, 1).points, Neighbourhood::Half.points());
        // Reduced takes more passes there, the same 7×7 and plain choice.
        let r = ParallelSettings::defaults_for(Neighbourhood::Reduced, false);
        let top = r.recipe_at(0, 5);
        assert_eq!(top.points, Neighbourhood::Full(7).points());
        assert_eq!((top.passes, top.coherence), (REDUCED_COARSE_PASSES, 0.0));
        assert_eq!(r.recipe_at(4, 5).points, Neighbourhood::Reduced.points());
        // 5×5 takes the 7×7 coarse levels with the plain choice it has.
        let five = ParallelSettings::defaults_for(Neighbourhood::Full(5), false);
        let top = five.recipe_at(0, 5);
        assert_eq!(top.points, Neighbourhood::Full(7).points());
        assert_eq!((top.passes, top.coherence), (COARSE_PASSES, 0.0));
        assert_eq!(five.recipe_at(4, 5).points, Neighbourhood::Full(5).points());
        // Morphs, solids and 7×7 keep one recipe.
        for (n, morph) in [
            (Neighbourhood::Half, true),
            (Neighbourhood::Reduced, true),
            (Neighbourhood::Full(5), true),
            (Neighbourhood::Full(7), false),
        ] {
            let s = ParallelSettings::defaults_for(n, morph);
            assert!(s.coarse.is_none(), "{n:?} morph {morph}");
            assert_eq!(s.recipe_at(0, 5).points, n.points());
            assert_eq!(s.most_points(), n.points().len());
        }
        assert!(ParallelSettings::default().coarse.is_none());
    }
}
