//! `texsyn fill`, `extend` and `synth`: the block method (and `synth
//! --method parallel`, which takes the same flags) from the command line:
//! flags to a validated [`Config`] and [`Mode`], the run, and the outputs
//! written atomically at the input's depth.

use std::path::Path;
use std::time::Instant;

use anyhow::{ensure, Context, Result};

use super::block_args::{
    config_with_defaults, parse_position, ExtendArgs, FillArgs, MethodArg, StitchArg, SynthArgs,
};
use super::{parallel, parse_size, progress, Common, ParallelArgs};
use crate::block::{self, Config, FillSource, Mode, Stitch, SynthMethod};
use crate::imaging::{self, ColorImage, DeepImage, PixelFormat};
use crate::lattice::{self, LatticeSpec};

/// Rejects outputs of `common` that name the same file, an input of
/// `inputs` (flag, path) or a level file of `--levels-dir`.
fn check_distinct(inputs: &[(&str, &Path)], common: &Common) -> Result<()> {
    let mut outputs: Vec<(&str, &Path)> = vec![("-o", &common.output)];
    if let Some(p) = &common.copy_map {
        crate::imaging::check_coord_map_path(p)?;
        outputs.push(("--copy-map", p));
    }
    if let Some(p) = &common.report {
        outputs.push(("--report", p));
    }
    crate::imaging::paths::check_files(&outputs, inputs, common.levels_dir.as_deref())
}

fn write_outputs(common: &Common, out: &block::Output, image: &DeepImage) -> Result<()> {
    imaging::save_image(&common.output, image)?;
    if let Some(p) = &common.copy_map {
        imaging::save_coord_map(p, out.image.width, out.image.height, &out.copy_map)?;
    }
    if let Some(dir) = &common.levels_dir {
        for (l, g) in out.levels.iter().enumerate() {
            imaging::save_gray(&dir.join(format!("level{l}.png")), g)?;
        }
    }
    if let Some(p) = &common.report {
        let json = serde_json::to_vec_pretty(&out.report)?;
        imaging::save_bytes(p, &json)?;
    }
    Ok(())
}

/// Checks the outputs before the run: writable, and their formats can hold
/// the `size` of the result.
fn check_outputs(common: &Common, size: (usize, usize)) -> Result<()> {
    imaging::check_writable(&common.output)?;
    imaging::check_output_size(&common.output, size.0, size.1)?;
    if let Some(p) = &common.copy_map {
        imaging::check_writable(p)?;
        imaging::check_output_size(p, size.0, size.1)?;
    }
    if let Some(dir) = &common.levels_dir {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create --levels-dir {}", dir.display()))?;
        imaging::check_writable(&dir.join("level0.png"))?;
    }
    if let Some(p) = &common.report {
        imaging::check_writable_any(p)?;
    }
    Ok(())
}

/// The full-depth images an output is copied from (ARCHITECTURE §3.11).
struct Copies {
    /// What the copy map points into.
    source: DeepImage,
    /// The photo of a fill from another source, whose own pixels are kept.
    photo: Option<DeepImage>,
}

impl Copies {
    fn of(source: DeepImage) -> Self {
        Self {
            source,
            photo: None,
        }
    }

    /// The output's pixel format: the photo's, or the source's.
    fn format(&self) -> PixelFormat {
        self.photo.as_ref().unwrap_or(&self.source).format
    }

    /// Refuses, before the run, what would lose depth or channels.
    fn check(&self, common: &Common) -> Result<()> {
        let format = self.format();
        ensure!(
            common.chroma_blur == 0 || format == PixelFormat::RGB8,
            "--chroma-blur works on 8-bit RGB images; this one is {format}: drop --chroma-blur"
        );
        imaging::check_output_format(&common.output, format)
    }

    /// The output at full depth from the run's copy map.
    fn output(&self, out: &block::Output, chroma_blur: bool) -> Result<DeepImage> {
        if chroma_blur {
            // Blurred colour is made, not copied (8-bit RGB only, checked before).
            return Ok(DeepImage::from_colour(&out.image));
        }
        let kept = self.photo.as_ref().zip(out.kept.as_deref());
        self.source
            .rebuild(&out.copy_map, out.image.width, out.image.height, kept)
    }
}

/// Runs one synthesis command end to end.
fn run_synthesis(
    sample: &ColorImage,
    mode: Mode,
    mut cfg: Config,
    common: &Common,
    copies: Copies,
) -> Result<()> {
    if common.lattice == Some(LatticeSpec::Auto) {
        cfg.lattice = lattice::detect(sample);
        super::report_found_lattice(cfg.lattice, common.run.quiet);
    }
    let size = match &mode {
        Mode::Fill { .. } => (sample.width, sample.height),
        Mode::Extend { width, height, .. } | Mode::Synth { width, height, .. } => (*width, *height),
    };
    check_outputs(common, size)?;
    copies.check(common)?;
    let run = &common.run;
    let pool = run.pool()?;
    let bars = progress::Bars::new(run.quiet);
    // No level can have more LBG seeds than ⌈√(sample pixels)⌉: refuse impossible probes now.
    let largest_sample = cfg
        .level_samples
        .iter()
        .map(|(_, s)| s.width * s.height)
        .fold(sample.width * sample.height, usize::max);
    let mut opened = run.open(cfg.seed, largest_sample)?;
    let backend = &mut opened.search;
    if !matches!(mode, Mode::Fill { .. }) || cfg.levels != 0 {
        // (Automatic levels of `fill` depend on the holes; checked per level then.)
        backend.check_levels(block::resolve_levels(sample.width, sample.height, &cfg))?;
    }
    let t = Instant::now();
    let out = pool.install(|| block::synthesize(sample, &mode, &cfg, backend, &bars))?;
    tracing::info!(seconds = t.elapsed().as_secs_f64(), search = %out.report.search, "synthesis done");
    let image = copies.output(&out, cfg.chroma_blur > 0)?;
    write_outputs(common, &out, &image)?;
    if !run.quiet {
        eprintln!(
            "wrote {} ({}×{} {}, {} levels, {:.2} s)",
            common.output.display(),
            out.image.width,
            out.image.height,
            image.format,
            out.report.levels,
            out.report.synthesis_seconds
        );
    }
    Ok(())
}

/// `texsyn fill`.
pub fn run_fill(a: &FillArgs) -> Result<()> {
    let mut inputs = vec![("input", a.input.as_path())];
    inputs.extend(a.mask.as_deref().map(|m| ("--mask", m)));
    inputs.extend(a.source.as_deref().map(|m| ("--source", m)));
    inputs.extend(a.source_mask.as_deref().map(|m| ("--source-mask", m)));
    check_distinct(&inputs, &a.common)?;
    let cfg = Config::try_from(&a.common)?;
    let photo = imaging::load_image(&a.input)?;
    let holes = match &a.mask {
        Some(m) => imaging::load_mask(m, photo.width, photo.height)?,
        None => imaging::load_alpha_mask(&a.input, &photo)?,
    };
    let Some(source_path) = &a.source else {
        let img = photo.search_colour();
        let mode = Mode::Fill {
            holes,
            source: None,
        };
        return run_synthesis(&img, mode, cfg, &a.common, Copies::of(photo));
    };
    let source = imaging::load_image(source_path)?;
    let region = match &a.source_mask {
        Some(m) => Some(imaging::load_mask(m, source.width, source.height)?),
        None => None,
    };
    if source.format != photo.format {
        tracing::info!(
            source = %source.format,
            photo = %photo.format,
            "the fill source is converted to the photo's pixel format"
        );
    }
    let source = source.converted(photo.format);
    // One view for both, so that their 8-bit values compare.
    let view = imaging::SearchView::of(&[&photo, &source]);
    let img = photo.search_colour_in(&view);
    let mode = Mode::Fill {
        holes,
        source: Some(FillSource {
            image: source.search_colour_in(&view),
            region,
        }),
    };
    let copies = Copies {
        source,
        photo: Some(photo),
    };
    run_synthesis(&img, mode, cfg, &a.common, copies)
}

/// `texsyn extend`.
pub fn run_extend(a: &ExtendArgs) -> Result<()> {
    check_distinct(&[("input", &a.input)], &a.common)?;
    let cfg = Config::try_from(&a.common)?;
    let (width, height) = parse_size(&a.size)?;
    let position = parse_position(&a.position)?;
    let deep = imaging::load_image(&a.input)?;
    run_synthesis(
        &deep.search_colour(),
        Mode::Extend {
            width,
            height,
            position,
        },
        cfg,
        &a.common,
        Copies::of(deep),
    )
}

/// The first flag of `flags` (name, given) that was given.
fn first_given<'a>(flags: &[(&'a str, bool)]) -> Option<&'a str> {
    flags
        .iter()
        .find(|(_, given)| *given)
        .map(|(flag, _)| *flag)
}

/// `texsyn synth`.
pub fn run_synth(a: &SynthArgs) -> Result<()> {
    if matches!(a.method, MethodArg::Parallel) {
        return run_parallel(a);
    }
    let parallel_flags = [
        ("--jitter", a.jitter.is_some()),
        ("--start", a.start.is_some()),
        ("--correct-every-level", a.correct_every_level),
        ("--histogram", a.histogram.is_some()),
        ("--passes", a.passes.is_some()),
        ("--fine-passes", a.fine_passes.is_some()),
        ("--copy-guard", a.copy_guard.is_some()),
        ("--k", a.k.is_some()),
        ("--coherence", a.coherence.is_some()),
        ("--coarse-neighbourhood", a.coarse_neighbourhood.is_some()),
        ("--coarse-passes", a.coarse_passes.is_some()),
        ("--candidate-cache", a.candidate_cache.is_some()),
    ];
    if let Some(flag) = first_given(&parallel_flags) {
        anyhow::bail!("{flag} belongs to --method parallel");
    }
    // `synth`'s own stitching default is path, and growth stitched by path
    // matches N = 13 windows, whose stitching band is a pixel wider
    // (ARCHITECTURE §3.12).
    let path_growth =
        matches!(a.method, MethodArg::Grow) && !matches!(a.common.stitch, Some(StitchArg::Hard));
    let neighbourhood = if path_growth {
        block::PATH_GROWTH_NEIGHBOURHOOD
    } else {
        Config::default().neighbourhood
    };
    let mut cfg = config_with_defaults(&a.common, Stitch::Path, neighbourhood)?;
    let (width, height) = parse_size(&a.size)?;
    let mut level_files = Vec::new();
    for spec in &a.level_samples {
        let (l, file) = spec
            .split_once('=')
            .with_context(|| format!("--level-sample '{spec}' is not L=FILE, e.g. 0=detail.png"))?;
        let l: usize = l
            .trim()
            .parse()
            .with_context(|| format!("level '{l}' in --level-sample is not a number"))?;
        level_files.push((l, Path::new(file)));
    }
    let mut inputs = vec![("input", a.input.as_path())];
    inputs.extend(level_files.iter().map(|&(_, f)| ("--level-sample", f)));
    check_distinct(&inputs, &a.common)?;
    let mut deep = imaging::load_image(&a.input)?;
    let mut level_samples = Vec::new();
    for (l, file) in level_files {
        level_samples.push((l, imaging::load_image(file)?));
    }
    // One view for the sample and its level samples, so that their
    // 8-bit values compare.
    let mut all = vec![&deep];
    all.extend(level_samples.iter().map(|(_, s)| s));
    let view = imaging::SearchView::of(&all);
    let img = deep.search_colour_in(&view);
    if path_growth && a.common.neighbourhood.is_none() {
        cfg.neighbourhood = block::growth_neighbourhood([img.width, img.height], cfg.levels);
    }
    for (l, level_sample) in level_samples {
        cfg.level_samples
            .push((l, level_sample.search_colour_in(&view)));
        if l == 0 {
            // The finest level's sample is what the output is copied from.
            deep = level_sample;
        }
    }
    let method = match a.method {
        MethodArg::Grow => SynthMethod::Grow,
        MethodArg::Scanline => SynthMethod::Scanline,
        MethodArg::Parallel => unreachable!("handled above"),
    };
    run_synthesis(
        &img,
        Mode::Synth {
            width,
            height,
            method,
        },
        cfg,
        &a.common,
        Copies::of(deep),
    )
}

/// `texsyn synth --method parallel`.
fn run_parallel(a: &SynthArgs) -> Result<()> {
    check_distinct(&[("input", &a.input)], &a.common)?;
    let c = &a.common;
    let block_flags = [
        ("--block", c.block.is_some()),
        ("--levels", c.levels.is_some()),
        ("--weights", c.weights.is_some()),
        ("--metric", c.metric.is_some()),
        ("--batch", c.batch.is_some()),
        ("--parent-window", c.parent_window.is_some()),
        ("--level-sample", !a.level_samples.is_empty()),
        ("--tileable", c.tileable),
        ("--colour-search", c.colour_search),
        ("--chroma-blur", c.chroma_blur != 0),
        ("--stitch", c.stitch.is_some()),
        ("--repeat-slack", c.repeat_slack.is_some()),
        ("--repeat-candidates", c.repeat_candidates.is_some()),
        ("--repeat-percent", c.repeat_percent.is_some()),
        ("--repeat-seam", c.repeat_seam.is_some()),
        ("--repeat-cap", c.repeat_cap.is_some()),
        ("--no-repeat-control", c.no_repeat_control),
        ("--levels-dir", c.levels_dir.is_some()),
        ("--report", c.report.is_some()),
    ];
    if let Some(flag) = first_given(&block_flags) {
        anyhow::bail!(
            "{flag} belongs to the block method and --method parallel would ignore it; drop it (--method parallel takes --neighbourhood, --jitter, --start, --correct-every-level, --histogram, --passes, --fine-passes, --copy-guard, --k, --coherence, --coarse-neighbourhood, --coarse-passes, --lattice, --seed, --coords and the run flags)"
        );
    }
    let args = ParallelArgs {
        neighbourhood: c.neighbourhood.clone().unwrap_or_else(|| "reduced".into()),
        jitter: a.jitter.clone(),
        start: a.start.clone().unwrap_or_else(|| "random".into()),
        seed: c.seed,
        correct_every_level: a.correct_every_level,
        passes: a.passes,
        fine_passes: a.fine_passes,
        copy_guard: a.copy_guard,
        k: a.k,
        coherence: a.coherence,
        coarse_neighbourhood: a.coarse_neighbourhood.clone(),
        coarse_passes: a.coarse_passes,
        histogram: a
            .histogram
            .unwrap_or(crate::parallel::driver::DEFAULT_HISTOGRAM),
        candidate_cache: a.candidate_cache.clone(),
        lattice: c.lattice,
        run: c.run.clone(),
    };
    parallel::run_synth(&a.input, &a.size, &c.output, c.copy_map.as_deref(), &args)
}
