//! `texsyn synth --method parallel`, `texsyn morph` and `texsyn replay`: the
//! synthesis on coordinates (ARCHITECTURE §10) from the command line.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use clap::Args;

use super::progress::Bars;
use super::{parse_size, RunArgs};
use crate::imaging::{self, ColorImage};
use crate::lattice::{Lattice, LatticeSpec};
use crate::parallel::cache::CandidateCache;
use crate::parallel::candidates::MAX_K;
use crate::parallel::driver::{default_coherence, CoarseLevels, Start, COARSE_PASSES};
use crate::parallel::synth::{self, MorphColour, Neighbourhood, ParallelSettings, Synthesis};
use crate::parallel::weights;

#[derive(Args, Debug)]
pub struct MorphArgs {
    /// The exemplars, two or more (one works too: a plain synthesis).
    #[arg(required = true)]
    pub exemplars: Vec<PathBuf>,
    /// Weight maps, one per exemplar, comma-separated, each the output size:
    /// grey levels, normalised to sum to 1 per pixel.
    #[arg(long, value_delimiter = ',', conflicts_with = "ramp")]
    pub weight_maps: Vec<PathBuf>,
    /// A linear ramp along x or y instead of weight maps: the first exemplar at
    /// one edge, the last at the other.
    #[arg(long)]
    pub ramp: Option<String>,
    /// Output image (PNG and the other formats of `synth`), written atomically.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Output size WxH.
    #[arg(long)]
    pub size: String,
    /// Also write each exemplar's coordinate map (16-bit PNG; with several
    /// exemplars FILE_1.png, FILE_2.png...).
    #[arg(long)]
    pub coords: Option<PathBuf>,
    /// The output colour: best (per pixel the exemplar whose neighbourhood
    /// fits best for its weight, so the middle of a ramp shows whole
    /// features of each) or weighted (Σ Wʲ·Eʲ(Sʲ), a double exposure where
    /// the weights are even).
    #[arg(long, default_value = "best")]
    pub colour: String,
    #[command(flatten)]
    pub settings: ParallelArgs,
}

/// Parses `--colour`.
fn parse_colour(s: &str) -> Result<MorphColour> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "best" => MorphColour::Best,
        "weighted" => MorphColour::Weighted,
        _ => anyhow::bail!("--colour '{s}' is not best or weighted"),
    })
}

/// The settings of a synthesis on coordinates.
#[derive(Args, Debug, Clone)]
pub struct ParallelArgs {
    /// Neighbourhood: reduced, half (half-reduced), 5 or 7 (full).
    #[arg(long, alias = "neighborhood", default_value = "reduced")]
    pub neighbourhood: String,
    /// Jitter strength r in [0, 1], or one per level, coarsest first
    /// (r1,r2,...; the last repeats). Default 1,0.8,0.6,0.4, 1,0.8,0.7,0.6
    /// for the 5 neighbourhood and 1,0.8,0.5,0.3 for reduced and half in `synth`. The paper's is 0.4 everywhere.
    #[arg(long)]
    pub jitter: Option<String>,
    /// The coarsest level's start: random (every offset alike) or tiled
    /// (the paper's §4.1, S(P) = P mod the exemplar size).
    #[arg(long, default_value = "random")]
    pub start: String,
    /// Random seed of the jitter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Correction passes per level, each of four sub-passes (1 to 64;
    /// default 9 for the 5 neighbourhood in `synth` (4 in `morph`) and 5
    /// for 7; 8 for half and 4 for reduced in `synth`, the paper's 2 in
    /// `morph`). Levels with their own coarse
    /// neighbourhood take --coarse-passes.
    #[arg(long)]
    pub passes: Option<usize>,
    /// Correction passes of the finest level (1 to 64; default 8 for the
    /// reduced and half neighbourhoods in `synth`, else as --passes): the finest level refines
    /// a layout the coarser ones decided, so more passes there sharpen
    /// without copying the sample.
    #[arg(long)]
    pub fine_passes: Option<usize>,
    /// Copy guard: no pixel moves to an offset from the exemplar that more
    /// than this share of the level already holds, so no copy of the
    /// exemplar grows past it (0 < share < 1; 0: off, the paper's; default
    /// 0.08 for the 5, reduced and half neighbourhoods in `synth`, and for
    /// every neighbourhood under lattice phase; off for the others).
    #[arg(long)]
    pub copy_guard: Option<f32>,
    /// k of the k-coherence candidate sets (1 to 16): each pixel compares
    /// 9·k candidates per exemplar. Default 8 for the 7 neighbourhood, 4 for
    /// the others.
    #[arg(long)]
    pub k: Option<usize>,
    /// Coherence weight c ≥ 0 of the correction's choice: a candidate that
    /// v of the pixel's 3×3 neighbours continue coherently has its distance
    /// scaled by 1 + c·(1 − v/9). Default 10 for reduced and half, 0 (the
    /// paper's plain choice) for 5 and 7.
    #[arg(long)]
    pub coherence: Option<f32>,
    /// The neighbourhood of every level above the finest: reduced, half, 5,
    /// 7, or same (as the finest). Default 7 for reduced and half in
    /// `synth` (the coarse levels lay out bricks, tiles and folds, and
    /// cost a quarter of the finest level's pixels and less), same
    /// elsewhere. It takes its own default coherence weight.
    #[arg(long, alias = "coarse-neighborhood")]
    pub coarse_neighbourhood: Option<String>,
    /// Correction passes of the levels above the finest where they have
    /// their own neighbourhood (1 to 64; default 16, 40 under reduced).
    /// --passes sets the others.
    #[arg(long)]
    pub coarse_passes: Option<usize>,
    /// Lattice phase of `synth` (`--lattice`, ARCHITECTURE §10): given, found
    /// in the sample (the default, `None`), or off. Morphs take none.
    #[arg(skip)]
    pub lattice: Option<LatticeSpec>,
    /// Correct every level, as the paper does. By default a level whose
    /// neighbourhood spans half the exemplar's smaller side or more is only
    /// jittered: there the exemplar itself is the one neighbourhood that
    /// matches everywhere, and correcting lets one offset copy it over the
    /// whole output (5×5 and 7×7 made tiled copies).
    #[arg(long)]
    pub correct_every_level: bool,
    /// Strength of the histogram matching of the blend before every
    /// correction sub-pass, 0 to 1 (Kopf et al.; 1: full, the default;
    /// 0: the paper's plain method, whose corrections favour flat regions
    /// and lose thin features such as cracks).
    #[arg(long, default_value_t = crate::parallel::driver::DEFAULT_HISTOGRAM)]
    pub histogram: f32,
    /// Keep each level's k-coherence candidate sets in this directory: a
    /// later run from the same exemplars skips their search (same output).
    #[arg(long, value_name = "DIR")]
    pub candidate_cache: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// A coordinate map (`--coords` of `synth --method parallel` or `morph`,
    /// or `--copy-map` of the block method).
    #[arg(long)]
    pub coords: PathBuf,
    /// Maps of the same material as the exemplar (height, normal, roughness...),
    /// each the exemplar's size; copied at their own depth and channels.
    #[arg(required = true)]
    pub maps: Vec<PathBuf>,
    /// Output directory: each map's replay under the map's file name.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// Parses the neighbourhood name.
pub fn parse_neighbourhood(s: &str) -> Result<Neighbourhood> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "reduced" => Neighbourhood::Reduced,
        "half" | "half-reduced" => Neighbourhood::Half,
        "5" | "5x5" => Neighbourhood::Full(5),
        "7" | "7x7" => Neighbourhood::Full(7),
        _ => anyhow::bail!(
            "--neighbourhood '{s}' is not one of reduced, half, 5 or 7 for the synthesis on coordinates"
        ),
    })
}

/// The coarse levels from `--coarse-neighbourhood` and `--coarse-passes`
/// over `default` (the neighbourhood's own coherence weight with them).
fn parse_coarse(
    name: Option<&str>,
    passes: Option<usize>,
    default: Option<CoarseLevels>,
) -> Result<Option<CoarseLevels>> {
    let coarse = match name {
        None => default,
        Some(n) if n.trim().eq_ignore_ascii_case("same") => None,
        Some(n) => {
            let neighbourhood = parse_neighbourhood(n).map_err(|_| {
                anyhow::anyhow!(
                    "--coarse-neighbourhood '{n}' is not one of reduced, half, 5, 7 or same"
                )
            })?;
            Some(CoarseLevels {
                neighbourhood,
                passes: COARSE_PASSES,
                coherence: default_coherence(neighbourhood),
            })
        }
    };
    match (coarse, passes) {
        (_, None) => Ok(coarse),
        (None, Some(_)) => anyhow::bail!(
            "--coarse-passes needs levels with their own neighbourhood; give --coarse-neighbourhood 7 (or drop --coarse-passes)"
        ),
        (Some(c), Some(p)) => {
            ensure!(
                (1..=64).contains(&p),
                "--coarse-passes {p} must be in 1..=64"
            );
            Ok(Some(CoarseLevels { passes: p, ..c }))
        }
    }
}

/// Opens `--candidate-cache`, if given.
pub(super) fn open_cache(dir: Option<&Path>) -> Result<Option<CandidateCache>> {
    dir.map(CandidateCache::open).transpose()
}

/// Parses `--jitter`: one strength in [0, 1], or one per level.
pub(super) fn parse_jitter(s: &str) -> Result<Vec<f64>> {
    s.split(',')
        .map(|v| {
            let r: f64 = v
                .trim()
                .parse()
                .with_context(|| format!("--jitter '{v}' is not a number"))?;
            ensure!((0.0..=1.0).contains(&r), "--jitter {r} must be in [0, 1]");
            Ok(r)
        })
        .collect()
}

impl ParallelArgs {
    fn settings(&self, colour: MorphColour, morph: bool) -> Result<ParallelSettings> {
        let h = self.histogram;
        ensure!(
            h.is_finite() && (0.0..=1.0).contains(&h),
            "--histogram {h} must be in [0, 1] (1: full matching, 0: the paper's plain method)"
        );
        let neighbourhood = parse_neighbourhood(&self.neighbourhood)?;
        let defaults = ParallelSettings::defaults_for(neighbourhood, morph);
        let passes = self.passes.unwrap_or(defaults.passes);
        ensure!(
            (1..=64).contains(&passes),
            "--passes {passes} must be in 1..=64"
        );
        // A --passes given alone sets every level of the main neighbourhood,
        // the finest included (coarse levels of their own take
        // --coarse-passes).
        let fine_passes = match (self.fine_passes, self.passes) {
            (Some(p), _) => Some(p),
            (None, Some(_)) => None,
            (None, None) => defaults.fine_passes,
        };
        if let Some(p) = fine_passes {
            ensure!((1..=64).contains(&p), "--fine-passes {p} must be in 1..=64");
        }
        let copy_guard = match self.copy_guard {
            None => defaults.copy_guard,
            Some(0.0) => None,
            Some(g) => {
                ensure!(
                    g.is_finite() && g > 0.0 && g < 1.0,
                    "--copy-guard {g} must be in (0, 1), or 0 to turn it off"
                );
                Some(g)
            }
        };
        let k = self.k.unwrap_or(defaults.k);
        ensure!(
            (1..=MAX_K).contains(&k),
            "--k {k} must be in 1..={MAX_K} (the candidates each pixel compares per neighbour)"
        );
        let coarse = parse_coarse(
            self.coarse_neighbourhood.as_deref(),
            self.coarse_passes,
            defaults.coarse,
        )?;
        let coherence = self.coherence.unwrap_or(defaults.coherence);
        ensure!(
            coherence.is_finite() && (0.0..=1000.0).contains(&coherence),
            "--coherence {coherence} must be in [0, 1000] (0: the paper's plain choice)"
        );
        Ok(ParallelSettings {
            passes,
            fine_passes,
            copy_guard,
            k,
            coherence,
            coarse,
            jitter: match &self.jitter {
                Some(j) => parse_jitter(j)?,
                None => defaults.jitter.clone(),
            },
            start: Start::parse(&self.start)?,
            seed: self.seed,
            every_level: self.correct_every_level,
            histogram: h,
            budget: self.run.budget(),
            colour,
            cache: open_cache(self.candidate_cache.as_deref())?,
            ..defaults
        })
    }

    /// Runs the morph of `exemplars` with `maps` on the local engine or the
    /// cluster, with a progress bar over the levels. `morph` picks the
    /// morph's defaults over the synthesis's
    /// ([`ParallelSettings::defaults_for`]).
    fn run(
        &self,
        exemplars: &[&ColorImage],
        maps: &[Vec<f32>],
        size: (usize, usize),
        colour: MorphColour,
        morph: bool,
        lattice: Option<Lattice>,
    ) -> Result<Synthesis> {
        let settings = ParallelSettings {
            lattice,
            ..self.settings(colour, morph)?
        };
        let pool = self.run.pool()?;
        let largest = exemplars
            .iter()
            .map(|e| e.width * e.height)
            .max()
            .unwrap_or(0);
        let mut opened = self.run.open(self.seed, largest)?;
        let bars = Bars::new(self.run.quiet);
        let t = Instant::now();
        let out = pool.install(|| {
            synth::morph(
                exemplars,
                maps,
                size.0,
                size.1,
                &settings,
                &mut opened.search,
                &bars,
            )
        })?;
        tracing::info!(
            seconds = t.elapsed().as_secs_f64(),
            levels = out.levels,
            "synthesis on coordinates done"
        );
        Ok(out)
    }
}

/// `synth --method parallel`: the output is copied whole-pixel from the
/// sample at its own depth through the coordinates.
pub fn run_synth(
    input: &Path,
    size: &str,
    output: &Path,
    coords: Option<&Path>,
    args: &ParallelArgs,
) -> Result<()> {
    let size = parse_size(size)?;
    check_output(output, coords, size)?;
    let deep = imaging::load_image(input)?;
    imaging::check_output_format(output, deep.format)?;
    let sample = deep.search_colour();
    // The grid is found by default (ARCHITECTURE §10).
    let lattice = match args.lattice.unwrap_or(LatticeSpec::Auto) {
        LatticeSpec::Auto => {
            let found = crate::lattice::detect(&sample);
            if found.is_some() || args.lattice.is_some() {
                super::report_found_lattice(found, args.run.quiet);
            }
            found
        }
        LatticeSpec::Given(l) => {
            l.validate([sample.width, sample.height])?;
            Some(l)
        }
        LatticeSpec::Off => None,
    };
    let ones = vec![vec![1.0f32; size.0 * size.1]];
    let t = Instant::now();
    let out = args.run(
        &[&sample],
        &ones,
        size,
        MorphColour::default(),
        false,
        lattice,
    )?;
    let image = deep.rebuild(&out.coords[0].coords, size.0, size.1, None)?;
    imaging::save_image(output, &image)?;
    if let Some(p) = coords {
        imaging::save_coord_map(p, size.0, size.1, &out.coords[0].coords)?;
    }
    done(args.run.quiet, output, size, out.levels, t);
    Ok(())
}

/// `texsyn morph`.
pub fn run_morph(a: &MorphArgs) -> Result<()> {
    let size = parse_size(&a.size)?;
    let colour = parse_colour(&a.colour)?;
    let m = a.exemplars.len();
    let coord_paths: Vec<PathBuf> = match &a.coords {
        None => Vec::new(),
        Some(p) if m == 1 => vec![p.clone()],
        Some(p) => (1..=m).map(|j| numbered(p, j)).collect(),
    };
    check_output(&a.output, None, size)?;
    for p in &coord_paths {
        imaging::check_coord_map_path(p)?;
        imaging::check_writable(p)?;
    }
    // Outputs never name an input or each other.
    let outputs: Vec<(&str, &Path)> = std::iter::once(("-o", a.output.as_path()))
        .chain(coord_paths.iter().map(|p| ("--coords", p.as_path())))
        .collect();
    let inputs: Vec<(&str, &Path)> = a
        .exemplars
        .iter()
        .map(|p| ("exemplar", p.as_path()))
        .chain(a.weight_maps.iter().map(|p| ("weight map", p.as_path())))
        .collect();
    crate::imaging::paths::check_files(&outputs, &inputs, None)?;
    let images = a
        .exemplars
        .iter()
        .map(|p| imaging::load_color(p))
        .collect::<Result<Vec<_>>>()?;
    let maps = match (&a.ramp, a.weight_maps.is_empty()) {
        (Some(axis), _) => weights::ramp(m, weights::parse_axis(axis)?, size.0, size.1),
        (None, false) => {
            ensure!(
                a.weight_maps.len() == m,
                "{} weight maps for {m} exemplars; give one per exemplar, in the same order",
                a.weight_maps.len()
            );
            let paths: Vec<&Path> = a.weight_maps.iter().map(PathBuf::as_path).collect();
            weights::load(&paths, size.0, size.1)?
        }
        (None, true) if m == 1 => vec![vec![1.0; size.0 * size.1]],
        (None, true) => {
            anyhow::bail!(
                "a morph of {m} exemplars needs --weight-maps WA.png,WB.png,... or --ramp x|y"
            )
        }
    };
    let refs: Vec<&ColorImage> = images.iter().collect();
    let t = Instant::now();
    let out = a.settings.run(&refs, &maps, size, colour, true, None)?;
    imaging::save_color(&a.output, &out.image)?;
    for (p, c) in coord_paths.iter().zip(&out.coords) {
        imaging::save_coord_map(p, size.0, size.1, &c.coords)?;
    }
    done(a.settings.run.quiet, &a.output, size, out.levels, t);
    Ok(())
}

/// `texsyn replay`: every map copied through the coordinates, at its own
/// depth and channels, with no search.
pub fn run_replay(a: &ReplayArgs) -> Result<()> {
    let (w, h, coords) = imaging::load_coord_map(&a.coords)?;
    let mut inputs: Vec<(&str, &Path)> = vec![("--coords", a.coords.as_path())];
    inputs.extend(a.maps.iter().map(|p| ("map", p.as_path())));
    let out_dir = imaging::OutputDir::create(&a.output, &inputs)?;
    let (most_x, most_y) = coords
        .iter()
        .fold((0, 0), |(x, y), c| (x.max(c[0]), y.max(c[1])));
    // The maps go into a temporary directory put in place at the end, so a
    // bad one leaves the output directory as it was.
    let mut names = std::collections::HashSet::new();
    let mut replayed = Vec::with_capacity(a.maps.len());
    for p in &a.maps {
        let name = p
            .file_name()
            .with_context(|| format!("{} names no file", p.display()))?;
        ensure!(
            names.insert(name.to_owned()),
            "two maps are named {}; replay writes each under its file name, so rename one",
            name.to_string_lossy()
        );
        let target = out_dir.path().join(name);
        let map = imaging::load_image(p)?;
        ensure!(
            (most_x as usize) < map.width && (most_y as usize) < map.height,
            "{} is {}x{}, but the coordinate map points up to ({most_x}, {most_y}); replay maps of the exemplar's size",
            p.display(),
            map.width,
            map.height
        );
        imaging::check_output_format(&target, map.format)?;
        replayed.push((target, map.rebuild(&coords, w, h, None)?));
    }
    for (target, image) in &replayed {
        imaging::save_image(target, image)?;
    }
    out_dir.commit()?;
    tracing::info!(out = %a.output.display(), maps = replayed.len(), "replayed");
    Ok(())
}

/// `FILE_j.ext` from `FILE.ext`.
fn numbered(p: &Path, j: usize) -> PathBuf {
    let stem = p
        .file_stem()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    let ext = p
        .extension()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    p.with_file_name(format!("{stem}_{j}.{ext}"))
}

fn check_output(output: &Path, coords: Option<&Path>, size: (usize, usize)) -> Result<()> {
    imaging::check_writable(output)?;
    imaging::check_output_size(output, size.0, size.1)?;
    if let Some(p) = coords {
        imaging::check_coord_map_path(p)?;
        imaging::check_writable(p)?;
    }
    Ok(())
}

fn done(quiet: bool, output: &Path, size: (usize, usize), levels: usize, t: Instant) {
    if !quiet {
        eprintln!(
            "wrote {} ({}×{}, {levels} levels, {:.2} s)",
            output.display(),
            size.0,
            size.1,
            t.elapsed().as_secs_f64()
        );
    }
}
