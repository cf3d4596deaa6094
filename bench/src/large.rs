//! `texsyn-bench large`: a large sample end to end (ARCHITECTURE §3.5, §6):
//! the pruned exact search against the unpruned exhaustive scan (same output,
//! checked) and, when it is installed, Embark's `texture-synthesis`.

use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use anyhow::{ensure, Result};
use clap::Args;
use texsyn::block::Silent;
use texsyn::search::LocalSearch;
use texsyn::{synthesize, Config, Mode, Output, SynthMethod};
use texsyn_engine::Engine;

#[derive(Args, Debug)]
pub struct LargeArgs {
    /// The sample, e.g. one of the 1024² CC0 photos of the shared texture set.
    pub sample: PathBuf,
    /// Output size WxH.
    #[arg(long, default_value = "1024x1024")]
    pub size: String,
    /// Also run the unpruned exhaustive scan (slow) and check the outputs match.
    #[arg(long)]
    pub unpruned: bool,
    /// Skip the peer even when `texture-synthesis` is on the PATH.
    #[arg(long)]
    pub no_peer: bool,
    /// Search threads (and the peer's threads; default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Write the outputs into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

fn synth(
    pool: &rayon::ThreadPool,
    sample: &texsyn::imaging::ColorImage,
    mode: &Mode,
    engine: Engine,
) -> Result<Output> {
    let mut backend = LocalSearch::new(engine);
    let cfg = Config::default();
    pool.install(|| synthesize(sample, mode, &cfg, &mut backend, &Silent))
}

fn print_levels(what: &str, out: &Output) {
    println!("{what}: {:.2} s synthesis", out.report.synthesis_seconds);
    for l in &out.report.per_level {
        println!(
            "    level {} refs {:>8} ({:>6.1} MB) queries {:>6}  build {:>6.2} s  search {:>7.2} s  pruned {}",
            l.level,
            l.reference_vectors,
            l.vector_bytes as f64 / 1e6,
            l.queries,
            l.build_seconds,
            l.search_seconds,
            crate::prune_text(l.prune)
        );
    }
}

pub fn run(a: &LargeArgs) -> Result<()> {
    let (w, h) = texsyn::cli::parse_size(&a.size)?;
    let sample = texsyn::imaging::load_color(&a.sample)?;
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = a.threads {
        b = b.num_threads(t);
    }
    let pool = b.build()?;
    let threads = pool.current_num_threads();
    println!(
        "{} ({}x{}) -> {w}x{h} | kernel {} | {threads} thread(s) | default settings",
        a.sample.display(),
        sample.width,
        sample.height,
        Engine::default().kernel().name()
    );
    let mode = Mode::Synth {
        width: w,
        height: h,
        method: SynthMethod::Grow,
    };
    let pruned = synth(&pool, &sample, &mode, Engine::default())?;
    print_levels("texsyn, pruned exact search", &pruned);
    if let Some(o) = &a.out {
        std::fs::create_dir_all(o)?;
        texsyn::imaging::save_color(&o.join("texsyn.png"), &pruned.image)?;
    }
    if a.unpruned {
        let full = synth(&pool, &sample, &mode, Engine::default().with_pruning(false))?;
        print_levels("texsyn, unpruned exhaustive scan", &full);
        ensure!(
            full.image == pruned.image && full.copy_map == pruned.copy_map,
            "the pruned and unpruned outputs differ"
        );
        println!(
            "    same output; pruned is {:.2}x faster",
            full.report.synthesis_seconds / pruned.report.synthesis_seconds
        );
    }
    if !a.no_peer {
        peer(a, w, h, threads, pruned.report.synthesis_seconds)?;
    }
    Ok(())
}

/// Runs Embark's `texture-synthesis` on the same sample, if installed.
fn peer(a: &LargeArgs, w: usize, h: usize, threads: usize, ours: f64) -> Result<()> {
    let dir = a.out.clone().unwrap_or_else(std::env::temp_dir);
    std::fs::create_dir_all(&dir)?;
    let out = dir.join("texture-synthesis.png");
    let t = Instant::now();
    let status = Command::new("texture-synthesis")
        .args([
            "--out-size",
            &format!("{w}x{h}"),
            "--threads",
            &threads.to_string(),
        ])
        .arg("--no-progress")
        .arg("--out")
        .arg(&out)
        .arg("generate")
        .arg(&a.sample)
        .status();
    match status {
        Ok(s) if s.success() => {
            let peer = t.elapsed().as_secs_f64();
            println!(
                "texture-synthesis (approximate): {peer:.2} s wall; texsyn / peer = {:.2}",
                ours / peer
            );
        }
        Ok(s) => println!("texture-synthesis failed: {s}"),
        Err(_) => println!(
            "texture-synthesis is not installed (cargo install texture-synthesis-cli --locked); skipped"
        ),
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct UpscaleArgs {
    /// The photo to enlarge.
    pub input: PathBuf,
    /// Where to write the large sample (written atomically).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Scale factor per side (8: 1024² → 8192²).
    #[arg(long, default_value_t = 8)]
    pub factor: u32,
    /// Keep the colour (default: the luminance only, a grey sample).
    #[arg(long)]
    pub colour: bool,
}

/// Enlarges a photo with a Lanczos-3 filter: a large sample whose texture is
/// the photo's at a coarser grain (a tiled photo would repeat exactly).
pub fn upscale(a: &UpscaleArgs) -> Result<()> {
    ensure!(
        (1..=16).contains(&a.factor),
        "--factor {} must be in 1..=16",
        a.factor
    );
    let img = image::open(&a.input)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", a.input.display()))?;
    let (w, h) = (img.width() * a.factor, img.height() * a.factor);
    let t = Instant::now();
    let big = img.resize_exact(w, h, image::imageops::FilterType::Lanczos3);
    if a.colour {
        let rgb = big.to_rgb8();
        let c = texsyn::imaging::ColorImage {
            width: w as usize,
            height: h as usize,
            rgb: rgb.into_raw(),
        };
        texsyn::imaging::save_color(&a.output, &c)?;
    } else {
        let g = texsyn::imaging::Gray {
            width: w as usize,
            height: h as usize,
            data: big.to_luma8().into_raw(),
        };
        texsyn::imaging::save_gray(&a.output, &g)?;
    }
    println!(
        "{} -> {} ({w}x{h}, {}) in {:.1} s",
        a.input.display(),
        a.output.display(),
        if a.colour { "colour" } else { "grey" },
        t.elapsed().as_secs_f64()
    );
    Ok(())
}
