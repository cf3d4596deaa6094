//! `texsyn match`: procedural texture matching and transformation
//! (Bourque–Dudek, ARCHITECTURE §12) from the command line.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};

use super::progress::{spinner, Bars};
use super::{parse_size, thread_pool};
use crate::budget::Budget;
use crate::imaging;
use crate::procedural::animate::{self, is_pattern};
use crate::procedural::catalogue::{self, BuildSettings, Catalogue};
use crate::procedural::shaders::listing;
use crate::procedural::transform::{self, TransformSettings};
use crate::procedural::{MatchConfig, MatchSettings, TransformConfig};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct MatchArgs {
    #[command(subcommand)]
    pub command: Option<MatchCommand>,
    /// The target texture (a photo or any image).
    pub target: Option<PathBuf>,
    /// The catalogue built by `texsyn match catalogue`.
    #[arg(long)]
    pub catalogue: Option<PathBuf>,
    /// The matched texture rendered (PNG and the other formats of `synth`),
    /// at the target's size unless --size is given; written atomically.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Also write the match as JSON: shader, parameters, colours, S_F, S_L,
    /// colour term, iterations, time (without it the JSON goes to stdout).
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Output size WxH (the pattern is resolution-free).
    #[arg(long)]
    pub size: Option<String>,
    #[command(flatten)]
    pub search: SearchArgs,
}

/// How the matching searches.
#[derive(Args, Debug, Clone)]
pub struct SearchArgs {
    /// Only these shaders, comma-separated (see `texsyn match shaders`).
    #[arg(long, value_delimiter = ',')]
    pub shaders: Vec<String>,
    /// Starting points per shader: its best catalogue samples.
    #[arg(long, default_value_t = 3)]
    pub starts: usize,
    /// Most simplex iterations per starting point.
    #[arg(long, default_value_t = 80)]
    pub iterations: u64,
    /// Drop a shader whose best catalogue distance exceeds the best shader's by more than this.
    #[arg(long, default_value_t = 0.1)]
    pub disparity: f64,
    /// Starting points, best after their first simplex run, that go on to
    /// the sweeps and the whole-number search.
    #[arg(long, default_value_t = 3)]
    pub finalists: usize,
    /// Shaders kept for the local search, best by catalogue distance plus
    /// the structure term (the periods per direction).
    #[arg(long, default_value_t = 3)]
    pub families: usize,
    /// Threads (default: all cores); the result is the same for any count.
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress display.
    #[arg(long, short)]
    pub quiet: bool,
}

impl TryFrom<&SearchArgs> for MatchSettings {
    type Error = anyhow::Error;

    fn try_from(a: &SearchArgs) -> Result<Self> {
        let s = MatchSettings {
            starts: a.starts,
            max_iters: a.iterations,
            shaders: (!a.shaders.is_empty()).then(|| a.shaders.clone()),
            disparity: a.disparity,
            finalists: a.finalists,
            families: a.families,
        };
        s.validate()?;
        Ok(s)
    }
}

#[derive(Subcommand, Debug)]
pub enum MatchCommand {
    /// Build the catalogue: each shader's parameter domain sampled by adaptive subdivision.
    #[command(after_help = "Example: texsyn match catalogue -o shaders.cat")]
    Catalogue(CatalogueArgs),
    /// A smooth transformation from texture A to texture B through parameter space.
    #[command(
        after_help = "Example: texsyn match transform a.png b.png --key k.png --frames 48 --catalogue shaders.cat -o frames/"
    )]
    Transform(TransformArgs),
    /// List the shader library: each shader's parameters, ranges and kinds.
    Shaders,
}

#[derive(Args, Debug)]
pub struct CatalogueArgs {
    /// The catalogue file (JSON), written atomically.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Render side of each sample (and of the matching analysis).
    #[arg(long, default_value_t = catalogue::DEFAULT_SIZE)]
    pub size: usize,
    /// Samples per shader.
    #[arg(long, default_value_t = catalogue::DEFAULT_SAMPLES)]
    pub samples: usize,
    /// Only these shaders, comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub shaders: Vec<String>,
    /// Threads (default: all cores); the catalogue is the same for any count.
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct TransformArgs {
    /// The first texture: an image (matched first) or a pattern JSON (`--params` of `texsyn match`).
    pub a: PathBuf,
    /// The last texture, likewise.
    pub b: PathBuf,
    /// Key-textures the transformation passes through, in order (repeatable).
    #[arg(long)]
    pub key: Vec<PathBuf>,
    /// Number of frames (at least 2).
    #[arg(long)]
    pub frames: usize,
    /// Output directory: frame_0000.png..., transform.gif, transform.webp, transform.json;
    /// a new or empty one, or an earlier output, replaced whole once all is written.
    #[arg(short, long)]
    pub output: PathBuf,
    /// The catalogue built by `texsyn match catalogue`.
    #[arg(long)]
    pub catalogue: Option<PathBuf>,
    /// Frame size WxH.
    #[arg(long, default_value = "256x256")]
    pub size: String,
    /// The n of the path cost (Σ eⁿ)^(1/n): larger favours many small steps.
    #[arg(long, default_value_t = 3.0)]
    pub exponent: f64,
    /// Largest distance (structure + colour term) between adjacent path points before a midpoint is inserted.
    #[arg(long, default_value_t = 0.1)]
    pub threshold: f64,
    /// Delay between the animations' frames in milliseconds (0: no GIF and no WebP).
    #[arg(long, alias = "gif-delay", default_value_t = 80)]
    pub delay: u32,
    #[command(flatten)]
    pub search: SearchArgs,
}

impl TryFrom<&CatalogueArgs> for BuildSettings {
    type Error = anyhow::Error;

    fn try_from(c: &CatalogueArgs) -> Result<Self> {
        let s = BuildSettings {
            size: c.size,
            samples: c.samples,
            shaders: (!c.shaders.is_empty()).then(|| c.shaders.clone()),
        };
        s.validate()?;
        Ok(s)
    }
}

impl TryFrom<&MatchArgs> for MatchConfig {
    type Error = anyhow::Error;

    fn try_from(a: &MatchArgs) -> Result<Self> {
        let target = a.target.clone().context(
            "give the target image: texsyn match TARGET.png --catalogue CAT -o OUT.png --params OUT.json (or a subcommand: catalogue, transform, shaders)",
        )?;
        let cfg = MatchConfig {
            target,
            catalogue: a.catalogue.clone().unwrap_or_default(),
            output: a.output.clone(),
            params: a.params.clone(),
            size: a.size.as_deref().map(parse_size).transpose()?,
            search: MatchSettings::try_from(&a.search)?,
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

impl TryFrom<&TransformArgs> for TransformConfig {
    type Error = anyhow::Error;

    fn try_from(t: &TransformArgs) -> Result<Self> {
        let cfg = TransformConfig {
            a: t.a.clone(),
            b: t.b.clone(),
            keys: t.key.clone(),
            catalogue: t.catalogue.clone().unwrap_or_default(),
            output: t.output.clone(),
            frames: t.frames,
            size: parse_size(&t.size)?,
            delay: t.delay,
            path: TransformSettings {
                exponent: t.exponent,
                threshold: t.threshold,
                ..TransformSettings::default()
            },
            search: MatchSettings::try_from(&t.search)?,
            budget: Budget::default(),
        };
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Entry point of `texsyn match`.
pub fn run(a: &MatchArgs) -> Result<()> {
    match &a.command {
        Some(MatchCommand::Catalogue(c)) => run_catalogue(c),
        Some(MatchCommand::Transform(t)) => run_transform(t),
        Some(MatchCommand::Shaders) => {
            use std::io::Write;
            // A closed pipe (e.g. `| head`) is not an error worth a message.
            let _ = std::io::stdout().lock().write_all(listing().as_bytes());
            Ok(())
        }
        None => run_match(a),
    }
}

fn run_catalogue(c: &CatalogueArgs) -> Result<()> {
    let settings = BuildSettings::try_from(c)?;
    imaging::check_writable_any(&c.output)?;
    let pool = thread_pool(c.threads)?;
    let t = Instant::now();
    let cat = pool.install(|| Catalogue::build(&settings, &Bars::new(c.quiet)))?;
    cat.save(&c.output)?;
    if !c.quiet {
        let (out, secs) = (c.output.display(), t.elapsed().as_secs_f64());
        eprintln!("wrote {out} ({}, {secs:.1} s)", cat.summary());
    }
    Ok(())
}

fn run_match(a: &MatchArgs) -> Result<()> {
    let cfg = MatchConfig::try_from(a)?;
    let pool = thread_pool(a.search.threads)?;
    let sp = spinner(
        a.search.quiet,
        format!("matching {} against the catalogue", cfg.target.display()),
    );
    let (m, json) = pool.install(|| cfg.run())?;
    sp.finish_and_clear();
    if let Some(json) = json {
        println!("{json}");
    }
    if !a.search.quiet {
        eprintln!("{}", m.summary());
    }
    Ok(())
}

fn run_transform(t: &TransformArgs) -> Result<()> {
    let cfg = TransformConfig::try_from(t)?;
    let q = t.search.quiet;
    let cat = Catalogue::load(&cfg.catalogue)?;
    let pool = thread_pool(t.search.threads)?;
    let started = Instant::now();
    let mut stops = Vec::new();
    for p in cfg.stops() {
        let sp = spinner(q || is_pattern(p), format!("matching {}", p.display()));
        let (pattern, m) = pool.install(|| animate::load_stop(p, &cat, &cfg.search))?;
        sp.finish_and_clear();
        if let (Some(m), false) = (&m, q) {
            eprintln!("{}: {}", p.display(), m.summary());
        }
        stops.push(pattern);
    }
    let sp = spinner(q, "planning the transformation".into());
    let path = pool.install(|| transform::transform(&cat, &stops, &cfg.path))?;
    sp.finish_and_clear();
    let frames = transform::frames(&path, cfg.frames);
    let bars = Bars::new(q);
    pool.install(|| animate::write_transform(&cfg, &stops, &path, &frames, started, &bars))?;
    if !q {
        let (n, out) = (cfg.frames, cfg.output.display());
        let secs = started.elapsed().as_secs_f64();
        eprintln!(
            "wrote {n} frames to {out} ({}, {secs:.1} s)",
            path.summary()
        );
    }
    Ok(())
}
