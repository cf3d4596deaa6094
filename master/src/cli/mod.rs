//! The `texsyn` command line: clap arguments turned into a validated
//! [`Config`] and [`Mode`], progress bars, and the outputs written atomically.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use texsyn_engine::{Engine, Metric, Weights};

use crate::block::{self, Config, FillSource, Mode, Position, SynthMethod};
use crate::imaging::{self, ColorImage, DeepImage, PixelFormat};
use crate::search::lbg::LbgSearch;
use crate::search::{LocalSearch, Plan, PlannedSearch};
pub use cluster::{run_status, ClusterArgs, ClusterSetup, StatusArgs};

mod args;
mod cluster;
mod compare;
mod parallel;
pub mod progress;

mod solid;
mod tiles;
pub use parallel::{MorphArgs, ParallelArgs, ReplayArgs};
pub use solid::SolidArgs;
mod procedural;
pub use compare::CompareArgs;
pub use procedural::{MatchArgs, MatchCommand};
pub use tiles::TilesCommand;

const EXAMPLES: &str = "Examples:
  texsyn extend sample.png -o out.png --size 1024x1024 --block 5 --neighbourhood 11 --levels 4 --tileable --seed 7
  texsyn fill photo.png --mask holes.png -o out.png
  texsyn fill photo.png --mask holes.png --source other.png --source-mask region.png -o out.png
  texsyn fill tile.png --mask-from-alpha --tileable -o out.png
  texsyn synth sample.png -o out.png --size 512x512
  texsyn synth sample.png -o out.png --size 256x256 --method scanline --report run.json
  texsyn synth sample.png -o out.png --size 512x512 --method parallel --neighbourhood half --coords c.png
  texsyn morph a.png b.png --ramp x -o morph.png --size 512x512
  texsyn replay --coords c.png height.png normal.png -o replayed/
  texsyn solid --view x=a.png --view y=b.png --view z=c.png --size 128 -o solid/
  texsyn tiles make sample.png --tiles 8 -o tiles/ && texsyn tiles assemble tiles/ --grid 8x8 -o wall.png
  texsyn compare sample.png out.png
  texsyn match catalogue -o shaders.cat && texsyn match photo.png --catalogue shaders.cat -o match.png --params match.json

Benchmarks are a separate binary: cargo run --release -p texsyn-bench -- paper";

#[derive(Parser, Debug)]
#[command(
    name = "texsyn",
    version,
    about = "Exact multi-scale block texture synthesis (Stahlhut): fill holes, extend and synthesise textures",
    after_help = EXAMPLES
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Fill the holes of an image (constrained synthesis); the mask is white where to fill.
    #[command(after_help = "Example: texsyn fill photo.png --mask holes.png -o out.png")]
    Fill(FillArgs),
    /// Grow a larger canvas around the sample.
    #[command(
        after_help = "Example: texsyn extend sample.png -o out.png --size 1024x1024 --tileable"
    )]
    Extend(ExtendArgs),
    /// Synthesise a new texture of any size from the sample.
    #[command(after_help = "Example: texsyn synth sample.png -o out.png --size 512x512 --seed 7")]
    Synth(SynthArgs),
    /// Search cluster tools.
    #[command(subcommand)]
    Cluster(ClusterCommand),
    /// Tile sets that connect in any order (Somol–Haindl) and their assembly.
    #[command(subcommand)]
    Tiles(TilesCommand),
    /// Morph several exemplars under weight maps, on coordinates (Manke–Wünsche §4).
    #[command(after_help = "Example: texsyn morph a.png b.png --ramp x -o out.png --size 512x512")]
    Morph(MorphArgs),
    /// A solid (3-D) texture from 2-D views across its axes (Manke–Wünsche §5).
    #[command(
        after_help = "Example: texsyn solid --view xyz=marble.png --size 128 -o marble_solid/"
    )]
    Solid(SolidArgs),
    /// Copy other maps of a material (height, normal...) through a coordinate or copy map.
    #[command(after_help = "Example: texsyn replay --coords c.png height.png -o replayed/")]
    Replay(ReplayArgs),
    /// Compare a texture with its sample (S_F, S_L, colour, patch fidelity, seams, copy and repetition), or measure a tile set.
    #[command(
        after_help = "Examples:\n  texsyn compare sample.png out.png\n  texsyn compare sample.png grid.png --tile 128x128 --wrap\n  texsyn compare set/"
    )]
    Compare(CompareArgs),
    /// Find the procedural shader and parameters that reproduce a texture, or transform one texture into another (Bourque–Dudek).
    #[command(
        after_help = "Examples:\n  texsyn match catalogue -o shaders.cat\n  texsyn match photo.png --catalogue shaders.cat -o match.png --params match.json\n  texsyn match transform a.png b.png --key k.png --frames 48 --catalogue shaders.cat -o frames/\n  texsyn match shaders"
    )]
    Match(MatchArgs),
}

#[derive(Subcommand, Debug)]
pub enum ClusterCommand {
    /// Table of the workers: version, cores, threads, load, calibrated throughput, memory in use.
    #[command(after_help = "Example: texsyn cluster status --hosts hosts.toml --token-file token")]
    Status(StatusArgs),
}

#[derive(Args, Debug, Clone)]
pub struct Common {
    /// Output image (png, jpg, tif, bmp, webp, exr); written atomically, at the
    /// input's depth and channels (the format must hold them: 16-bit in png or
    /// tif, float in exr or tif, alpha not in jpg).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Block size B (odd, 1..=11).
    #[arg(long, default_value_t = 5)]
    pub block: usize,
    /// Neighbourhood size N (odd, larger than the block; default 11). With
    /// `synth --method parallel`: reduced (default), half, 5 or 7.
    #[arg(long, alias = "neighborhood")]
    pub neighbourhood: Option<String>,
    /// Parent window M on the coarser level (odd; default covers N).
    #[arg(long)]
    pub parent_window: Option<usize>,
    /// Pyramid levels (0 = automatic).
    #[arg(long, default_value_t = 0)]
    pub levels: usize,
    /// Weights of the two neighbourhood parts, HI,LO (integers).
    #[arg(long, default_value = "1,2")]
    pub weights: String,
    /// Distance metric.
    #[arg(long, value_enum, default_value_t = MetricArg::L1)]
    pub metric: MetricArg,
    /// Make the output tile seamlessly (toroidal canvas).
    #[arg(long)]
    pub tileable: bool,
    /// Random seed (seed patch, noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Deterministic batch size K (1 = the paper's strict block order).
    #[arg(long, default_value_t = 16)]
    pub batch: usize,
    /// Chroma blur radius at patch borders (0 = off).
    #[arg(long, default_value_t = 0)]
    pub chroma_blur: usize,
    /// How a copied block meets the pixels around it: `hard` (the block's square
    /// edge) or `path` (its reference continues into a band of up to 3
    /// synthesised pixels, up to a minimum-error path; Somol–Haindl).
    #[arg(long, value_enum, default_value_t = StitchArg::Hard)]
    pub stitch: StitchArg,
    /// Full-colour search: compare Y, Cb and Cr neighbourhoods (3× the work), for
    /// textures whose structure and colour disagree. Runs on this machine.
    #[arg(long)]
    pub colour_search: bool,
    /// Also write the copy map: a 16-bit RGB PNG with R = source x, G =
    /// source y (exact; `texsyn replay` reads it).
    #[arg(long, alias = "coords")]
    pub copy_map: Option<PathBuf>,
    /// Also write each level's luminance into this directory.
    #[arg(long)]
    pub levels_dir: Option<PathBuf>,
    /// Also write a JSON run report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Search threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Search kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    pub kernel: String,
    /// Search plan per pyramid level, coarsest first, each local, cluster, lbg or
    /// cluster-lbg: e.g. local,local,lbg or cluster,cluster,cluster; or exact (exhaustive everywhere, the cluster for large
    /// levels when workers are given); or auto (LBG, approximate, for levels above the cost budget).
    #[arg(long, default_value = "exact")]
    pub search: String,
    /// LBG: partitions searched per query (the P nearest seeds; 1..=seeds of the level).
    #[arg(long, default_value_t = crate::search::lbg::DEFAULT_PROBES)]
    pub lbg_probes: usize,
    /// LBG: stop training when the relative change of the total seed displacement
    /// falls below this (0 < T < 1).
    #[arg(long, default_value_t = texsyn_engine::lbg::DEFAULT_THRESHOLD)]
    pub lbg_threshold: f64,
    /// Most megabytes the reference vectors of one level may take on this
    /// machine (default: what the host or its cgroup still has). A level over
    /// the budget stops the run with an error before it is built.
    #[arg(long, value_name = "MB")]
    pub max_memory: Option<u64>,
    /// How a level's vectors are held on this machine: dense (built once,
    /// fastest), planes (gathered from the sample as they are scanned: about
    /// one byte per sample pixel, for large samples) or auto (dense up to
    /// 1 GiB and half the memory left, planes beyond). Same output either way.
    #[arg(long, value_name = "STORE", default_value = "auto")]
    pub vector_store: String,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
    #[command(flatten)]
    pub cluster: ClusterArgs,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum StitchArg {
    Hard,
    Path,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum MetricArg {
    L1,
    L2,
}

#[derive(Args, Debug)]
pub struct FillArgs {
    /// The image with holes.
    pub input: PathBuf,
    /// Mask image of the same size: white = fill, black = keep (a pixel is a
    /// hole when its luminance times its opacity is at least half the range;
    /// 8- or 16-bit).
    #[arg(long, required_unless_present = "mask_from_alpha")]
    pub mask: Option<PathBuf>,
    /// Take the holes from the image's own alpha channel: a pixel is a hole
    /// where its alpha is below half the range (128 of 255, 32768 of 65535, 0.5).
    #[arg(long, conflicts_with = "mask")]
    pub mask_from_alpha: bool,
    /// Fill from this image instead of the photo itself: the search and the
    /// copies use only it (converted to the photo's depth and channels).
    #[arg(long)]
    pub source: Option<PathBuf>,
    /// Copy only from the white part of the --source (same size as the source;
    /// read like --mask).
    #[arg(long, requires = "source")]
    pub source_mask: Option<PathBuf>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct ExtendArgs {
    /// The sample texture.
    pub input: PathBuf,
    /// Canvas size WxH.
    #[arg(long)]
    pub size: String,
    /// Where the sample goes: center or X,Y (top-left corner).
    #[arg(long, default_value = "center")]
    pub position: String,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// The sample texture.
    pub input: PathBuf,
    /// Output size WxH.
    #[arg(long)]
    pub size: String,
    /// grow: from a seeded sample patch; scanline: Stahlhut's full synthesis;
    /// parallel: pixels on exemplar coordinates (Lefebvre–Hoppe, Manke–Wünsche).
    #[arg(long, value_enum, default_value_t = MethodArg::Grow)]
    pub method: MethodArg,
    /// --method parallel: jitter strength r in [0, 1], or one per level,
    /// coarsest first (r1,r2,...).
    #[arg(long)]
    pub jitter: Option<String>,
    /// Texture mixing: use FILE as the sample of pyramid level L (0 = finest), as L=FILE.
    #[arg(long = "level-sample", value_name = "L=FILE")]
    pub level_samples: Vec<String>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(ValueEnum, Debug, Clone, Copy)]
pub enum MethodArg {
    Grow,
    Scanline,
    Parallel,
}

/// Parses the command line. A usage error (unknown flag, bad value) is
/// printed as one line `texsyn: error: ...` and exits with code 1; help and
/// version go out as clap prints them.
pub fn parse_args() -> Cli {
    texsyn_proto::cli::parse_or_exit("texsyn")
}

pub use args::{parse_dims, parse_size};
pub use texsyn_proto::cli::one_line;

use texsyn_proto::cli::check_seconds;
pub use texsyn_proto::cli::parse_seconds;

/// `v` seconds of the flag `flag` as a [`Duration`], checked against
/// `min..=max` again (for callers of the library that skip the parser).
pub fn seconds(flag: &str, v: f64, min: f64, max: f64) -> Result<Duration> {
    let v =
        check_seconds(v, &v.to_string(), min, max).map_err(|e| anyhow::anyhow!("{flag}: {e}"))?;
    Duration::try_from_secs_f64(v).with_context(|| format!("{flag} {v} is not a duration"))
}

fn parse_weights(s: &str) -> Result<Weights> {
    let (a, b) = s
        .split_once(',')
        .with_context(|| format!("weights '{s}' are not HI,LO, e.g. --weights 1,2"))?;
    let hi: u32 = a
        .trim()
        .parse()
        .with_context(|| format!("weight '{a}' is not a whole number"))?;
    let lo: u32 = b
        .trim()
        .parse()
        .with_context(|| format!("weight '{b}' is not a whole number"))?;
    Ok(Weights::new(hi, lo)?)
}

fn parse_position(s: &str) -> Result<Position> {
    if s.eq_ignore_ascii_case("center") || s.eq_ignore_ascii_case("centre") {
        return Ok(Position::Center);
    }
    let (x, y) = s
        .split_once(',')
        .with_context(|| format!("position '{s}' is not 'center' or X,Y, e.g. --position 10,20"))?;
    let coordinate = |name: &str, v: &str| -> Result<usize> {
        let n: u64 = v.trim().parse().with_context(|| {
            format!("{name} '{v}' in --position '{s}' is not a whole number ≥ 0")
        })?;
        ensure!(
            n < imaging::MAX_SIDE as u64,
            "{name} {n} in --position '{s}' is outside any canvas (at most {} pixels per side); give X,Y inside the --size canvas",
            imaging::MAX_SIDE
        );
        Ok(n as usize)
    };
    Ok(Position::At(coordinate("x", x)?, coordinate("y", y)?))
}

impl TryFrom<&Common> for Config {
    type Error = anyhow::Error;

    fn try_from(c: &Common) -> Result<Self> {
        let cfg = Config {
            block: c.block,
            neighbourhood: match c.neighbourhood.as_deref() {
                None => 11,
                Some(n) => n.trim().parse().with_context(|| {
                    format!("--neighbourhood '{n}' is not a whole number; names like reduced or half belong to --method parallel")
                })?,
            },
            parent_window: c.parent_window,
            levels: c.levels,
            weights: parse_weights(&c.weights)?,
            metric: match c.metric {
                MetricArg::L1 => Metric::L1,
                MetricArg::L2 => Metric::L2,
            },
            tileable: c.tileable,
            seed: c.seed,
            batch: c.batch,
            chroma_blur: c.chroma_blur,
            level_samples: Vec::new(),
            colour_search: c.colour_search,
            stitch: match c.stitch {
                StitchArg::Hard => block::Stitch::Hard,
                StitchArg::Path => block::Stitch::Path,
            },
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

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

pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        ensure!((1..=1024).contains(&t), "--threads {t} must be in 1..=1024");
        b = b.num_threads(t);
    }
    b.build().context("cannot start the search threads")
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
    cfg: Config,
    common: &Common,
    copies: Copies,
) -> Result<()> {
    let size = match &mode {
        Mode::Fill { .. } => (sample.width, sample.height),
        Mode::Extend { width, height, .. } | Mode::Synth { width, height, .. } => (*width, *height),
    };
    check_outputs(common, size)?;
    copies.check(common)?;
    let engine = Engine::with_kernel_name(&common.kernel)?;
    let pool = thread_pool(common.threads)?;
    let bars = progress::Bars::new(common.quiet);
    let plan: Plan = common.search.parse()?;
    let lbg = LbgSearch::new(engine, common.lbg_probes, common.lbg_threshold, cfg.seed)?;
    // No level can have more LBG seeds than ⌈√(sample pixels)⌉: refuse impossible probes now.
    let most_pixels = cfg
        .level_samples
        .iter()
        .map(|(_, s)| s.width * s.height)
        .fold(sample.width * sample.height, usize::max);
    lbg.check_vectors(most_pixels)?;
    // Local workers (if any) live until the end of this function, also on error;
    // the backend is declared after them, so it is dropped (ending the job on
    // the workers) before they are killed.
    let cluster = common.cluster.setup()?;
    let (cluster_options, _local_workers, _ssh_workers) = match cluster {
        Some(c) => (Some(c.options), c.local, c.ssh),
        None => (None, None, None),
    };
    let mut local = LocalSearch::new(engine)
        .with_storage(texsyn_engine::Storage::from_name(&common.vector_store)?);
    if let Some(mb) = common.max_memory {
        local = local.with_max_memory(mb.saturating_mul(1 << 20));
    }
    let mut backend = PlannedSearch::new(plan, local).with_lbg(Box::new(lbg));
    backend.lbg_probes = u32::try_from(common.lbg_probes).unwrap_or(u32::MAX);
    if let Some(options) = cluster_options {
        let cluster = crate::cluster::ClusterSearch::connect(options, engine)?;
        backend = backend.with_cluster(Box::new(cluster));
    }
    if !matches!(mode, Mode::Fill { .. }) || cfg.levels != 0 {
        // (Automatic levels of `fill` depend on the holes; checked per level then.)
        backend.check_levels(block::resolve_levels(sample.width, sample.height, &cfg))?;
    }
    let t = Instant::now();
    let out = pool.install(|| block::synthesize(sample, &mode, &cfg, &mut backend, &bars))?;
    tracing::info!(seconds = t.elapsed().as_secs_f64(), search = %out.report.search, "synthesis done");
    let image = copies.output(&out, cfg.chroma_blur > 0)?;
    write_outputs(common, &out, &image)?;
    if !common.quiet {
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

/// Entry point of the binary after argument parsing.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Fill(a) => {
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
        Command::Extend(a) => {
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
        Command::Synth(a) if matches!(a.method, MethodArg::Parallel) => {
            check_distinct(&[("input", &a.input)], &a.common)?;
            let c = &a.common;
            ensure!(
                a.level_samples.is_empty()
                    && !c.tileable
                    && !c.colour_search
                    && c.chroma_blur == 0
                    && c.stitch == StitchArg::Hard
                    && c.levels_dir.is_none()
                    && c.report.is_none(),
                "--method parallel takes --neighbourhood, --jitter, --seed, --threads, --coords (--copy-map) and the cluster flags; drop the block method's --level-sample, --tileable, --colour-search, --chroma-blur, --stitch, --levels-dir and --report"
            );
            let args = ParallelArgs {
                neighbourhood: c.neighbourhood.clone().unwrap_or_else(|| "reduced".into()),
                jitter: a.jitter.clone().unwrap_or_else(|| "0.4".into()),
                seed: c.seed,
                threads: c.threads,
                quiet: c.quiet,
                cluster: c.cluster.clone(),
            };
            parallel::run_synth(&a.input, &a.size, &c.output, c.copy_map.as_deref(), &args)
        }
        Command::Synth(a) => {
            ensure!(a.jitter.is_none(), "--jitter belongs to --method parallel");
            let mut cfg = Config::try_from(&a.common)?;
            let (width, height) = parse_size(&a.size)?;
            let mut level_files = Vec::new();
            for spec in &a.level_samples {
                let (l, file) = spec.split_once('=').with_context(|| {
                    format!("--level-sample '{spec}' is not L=FILE, e.g. 0=detail.png")
                })?;
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
        Command::Cluster(ClusterCommand::Status(a)) => run_status(&a),
        Command::Tiles(t) => tiles::run(t),
        Command::Morph(a) => parallel::run_morph(&a),
        Command::Replay(a) => parallel::run_replay(&a),
        Command::Solid(a) => solid::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Match(a) => procedural::run(&a),
    }
}
