//! `texsyn match`: procedural texture matching and transformation
//! (Bourque–Dudek, ARCHITECTURE §12) from the command line.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use super::{parse_size, thread_pool};
use crate::imaging::paths;
use crate::imaging::{self, animation, ColorImage};
use crate::procedural::catalogue::{self, BuildSettings, Catalogue};
use crate::procedural::transform::{self, TransformSettings};
use crate::procedural::LIBRARY;
use crate::procedural::{match_texture, MatchResult, MatchSettings, Pattern};

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
    /// Output directory: frame_0000.png..., transform.gif, transform.webp, transform.json.
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

fn bar(quiet: bool, len: u64, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    b.set_style(
        ProgressStyle::with_template(template)
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    b
}

fn spinner(quiet: bool, message: String) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new_spinner();
    b.set_message(message);
    b.enable_steady_tick(std::time::Duration::from_millis(120));
    b
}

fn load_catalogue(path: Option<&Path>) -> Result<Catalogue> {
    let p = path.context(
        "no --catalogue given; build one once with: texsyn match catalogue -o shaders.cat, then pass --catalogue shaders.cat",
    )?;
    Catalogue::load(p)
}

/// Entry point of `texsyn match`.
pub fn run(a: &MatchArgs) -> Result<()> {
    match &a.command {
        Some(MatchCommand::Catalogue(c)) => run_catalogue(c),
        Some(MatchCommand::Transform(t)) => run_transform(t),
        Some(MatchCommand::Shaders) => {
            print_shaders();
            Ok(())
        }
        None => run_match(a),
    }
}

fn print_shaders() {
    use std::io::Write;
    let mut out = String::new();
    for s in LIBRARY {
        out.push_str(&format!("{}: {}\n", s.name, s.doc));
        for p in s.params {
            out.push_str(&format!(
                "  {:<11} {:?} {}..{}  {}\n",
                p.name, p.kind, p.min, p.max, p.doc
            ));
        }
        out.push_str("  colour_low, colour_high: RGB at pattern 0 and 1 (fitted, not searched)\n");
    }
    // A closed pipe (e.g. `| head`) is not an error worth a message.
    let _ = std::io::stdout().lock().write_all(out.as_bytes());
}

fn run_catalogue(c: &CatalogueArgs) -> Result<()> {
    let settings = BuildSettings {
        size: c.size,
        samples: c.samples,
        shaders: (!c.shaders.is_empty()).then(|| c.shaders.clone()),
    };
    settings.validate()?;
    imaging::check_writable_any(&c.output)?;
    let pool = thread_pool(c.threads)?;
    let count = catalogue::selected(settings.shaders.as_deref())?.len();
    let b = bar(
        c.quiet,
        (count * settings.samples) as u64,
        "catalogue [{bar:40}] {pos}/{len} samples {elapsed_precise} eta {eta}",
    );
    let t = Instant::now();
    let cat = pool.install(|| Catalogue::build(&settings, &|| b.inc(1)))?;
    b.finish_and_clear();
    cat.save(&c.output)?;
    if !c.quiet {
        eprintln!(
            "wrote {} ({} shaders, {} samples at {}², {:.1} s)",
            c.output.display(),
            cat.shaders.len(),
            cat.shaders.iter().map(|s| s.samples.len()).sum::<usize>(),
            cat.size,
            t.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

fn run_match(a: &MatchArgs) -> Result<()> {
    let target_path = a.target.as_deref().context(
        "give the target image: texsyn match TARGET.png --catalogue CAT -o OUT.png --params OUT.json (or a subcommand: catalogue, transform, shaders)",
    )?;
    let mut outputs: Vec<(&str, &Path)> = Vec::new();
    if let Some(o) = &a.output {
        imaging::check_writable(o)?;
        outputs.push(("-o", o));
    }
    if let Some(p) = &a.params {
        imaging::check_writable_any(p)?;
        outputs.push(("--params", p));
    }
    let mut inputs = vec![("target", target_path)];
    inputs.extend(a.catalogue.as_deref().map(|c| ("--catalogue", c)));
    paths::check_files(&outputs, &inputs, None)?;
    let settings = MatchSettings::try_from(&a.search)?;
    let size = a.size.as_deref().map(parse_size).transpose()?;
    let target = imaging::load_color(target_path)?;
    let (w, h) = size.unwrap_or((target.width, target.height));
    if let Some(o) = &a.output {
        imaging::check_output_size(o, w, h)?;
    }
    let cat = load_catalogue(a.catalogue.as_deref())?;
    let pool = thread_pool(a.search.threads)?;
    let sp = spinner(
        a.search.quiet,
        format!("matching {} against the catalogue", target_path.display()),
    );
    let m = pool.install(|| match_texture(&target, &cat, &settings))?;
    sp.finish_and_clear();
    let json = serde_json::to_string_pretty(&m.to_json())?;
    if let Some(o) = &a.output {
        let img = pool.install(|| m.pattern.render(w, h));
        imaging::save_color(o, &img)?;
    }
    match &a.params {
        Some(p) => imaging::save_bytes(p, json.as_bytes())?,
        None => println!("{json}"),
    }
    if !a.search.quiet {
        eprintln!("{}", summary(&m));
    }
    Ok(())
}

fn summary(m: &MatchResult) -> String {
    format!(
        "matched {} (S_F {:.3}, S_L {:.3}, colour {:.3}) in {:.1} s, {} iterations, {} renders",
        m.pattern.shader.name, m.s_f, m.s_l, m.colour, m.seconds, m.iterations, m.evaluations
    )
}

/// A stop of a transformation: a pattern JSON as given, or an image matched.
fn stop(path: &Path, cat: &Catalogue, settings: &MatchSettings, quiet: bool) -> Result<Pattern> {
    let is_json = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read the pattern {}", path.display()))?;
        let v: serde_json::Value = serde_json::from_str(&text)
            .with_context(|| format!("{} is not JSON", path.display()))?;
        return Pattern::from_json(&v).with_context(|| {
            format!(
                "{} is not a pattern written by texsyn match --params",
                path.display()
            )
        });
    }
    let img: ColorImage = imaging::load_color(path)?;
    let sp = spinner(quiet, format!("matching {}", path.display()));
    let m = match_texture(&img, cat, settings)?;
    sp.finish_and_clear();
    if !quiet {
        eprintln!("{}: {}", path.display(), summary(&m));
    }
    Ok(m.pattern)
}

fn run_transform(t: &TransformArgs) -> Result<()> {
    ensure!(
        (2..=10_000).contains(&t.frames),
        "--frames {} must be in 2..=10000",
        t.frames
    );
    let (w, h) = parse_size(&t.size)?;
    let tsettings = TransformSettings {
        exponent: t.exponent,
        threshold: t.threshold,
        ..TransformSettings::default()
    };
    tsettings.validate()?;
    let settings = MatchSettings::try_from(&t.search)?;
    let mut inputs: Vec<(&str, &Path)> = vec![("A", &t.a), ("B", &t.b)];
    inputs.extend(t.key.iter().map(|k| ("--key", k.as_path())));
    inputs.extend(t.catalogue.as_deref().map(|c| ("--catalogue", c)));
    for (flag, p) in &inputs {
        ensure!(
            p.is_file(),
            "the {flag} {} does not exist or is not a file",
            p.display()
        );
    }
    std::fs::create_dir_all(&t.output)
        .with_context(|| format!("cannot create the output directory {}", t.output.display()))?;
    let first = t.output.join("frame_0000.png");
    imaging::check_writable(&first)?;
    let names: Vec<PathBuf> = (0..t.frames)
        .map(|i| t.output.join(format!("frame_{i:04}.png")))
        .chain([
            t.output.join("transform.gif"),
            t.output.join("transform.webp"),
            t.output.join("transform.json"),
        ])
        .collect();
    let outputs: Vec<(&str, &Path)> = names.iter().map(|p| ("-o", p.as_path())).collect();
    paths::check_files(&outputs, &inputs, None)?;
    let cat = load_catalogue(t.catalogue.as_deref())?;
    let pool = thread_pool(t.search.threads)?;
    let started = Instant::now();
    let q = t.search.quiet;
    let mut stops = vec![pool.install(|| stop(&t.a, &cat, &settings, q))?];
    for k in &t.key {
        stops.push(pool.install(|| stop(k, &cat, &settings, q))?);
    }
    stops.push(pool.install(|| stop(&t.b, &cat, &settings, q))?);
    let sp = spinner(q, "planning the transformation".into());
    let path = pool.install(|| transform::transform(&cat, &stops, &tsettings))?;
    sp.finish_and_clear();
    let frames = transform::frames(&path, t.frames);
    let b = bar(q, frames.len() as u64, "frames [{bar:40}] {pos}/{len}");
    let mut images = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let img = pool.install(|| f.render(w, h));
        imaging::save_color(&names[i], &img)?;
        images.push(img);
        b.inc(1);
    }
    b.finish_and_clear();
    if t.delay > 0 {
        let gif = animation::encode_gif(&images, t.delay)?;
        imaging::save_bytes(&names[t.frames], &gif)?;
        let webp = animation::encode_webp(&images, t.delay)?;
        imaging::save_bytes(&names[t.frames + 1], &webp)?;
    }
    let report = serde_json::json!({
        "stops": stops.iter().map(Pattern::to_json).collect::<Vec<_>>(),
        "path_points": path.points.len(),
        "path_length": path.steps.iter().sum::<f64>(),
        "largest_step": path.steps.iter().cloned().fold(0.0, f64::max),
        "jumps": path.jumps.iter().filter(|&&j| j).count(),
        "seconds": started.elapsed().as_secs_f64(),
        "frames": frames.iter().map(Pattern::to_json).collect::<Vec<_>>(),
    });
    imaging::save_bytes(
        &names[t.frames + 2],
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    if !q {
        eprintln!(
            "wrote {} frames to {} ({} path points, {} jump{}, {:.1} s)",
            t.frames,
            t.output.display(),
            path.points.len(),
            path.jumps.iter().filter(|&&j| j).count(),
            if path.jumps.iter().filter(|&&j| j).count() == 1 {
                ""
            } else {
                "s"
            },
            started.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
