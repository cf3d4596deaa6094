//! `texsyn-bench match`: the figures of procedural matching (ARCHITECTURE
//! §12): the catalogue's build time, recovery of synthetic targets per
//! shader (10 random draws each, the criterion: every continuous
//! parameter and colour channel within 5% of its range, whole numbers
//! exact), match time per target, and matches of photos with their scores.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use texsyn::imaging;
use texsyn::procedural::catalogue::{BuildSettings, Catalogue};
use texsyn::procedural::{match_texture, recovery_trials, MatchSettings};
use texsyn::procedural::{Kind, LIBRARY};

#[derive(Args)]
pub struct MatchArgs {
    /// Random draws per shader.
    #[arg(long, default_value_t = 10)]
    draws: usize,
    /// Seed of the first draw.
    #[arg(long, default_value_t = 1000)]
    seed: u64,
    /// Catalogue render side.
    #[arg(long, default_value_t = 128)]
    size: usize,
    /// Catalogue samples per shader.
    #[arg(long, default_value_t = 200)]
    samples: usize,
    /// Only these shaders (comma-separated).
    #[arg(long, value_delimiter = ',')]
    shaders: Vec<String>,
    /// Photos to match with every shader (skips nothing; none: no photo part).
    #[arg(long, value_delimiter = ',')]
    photos: Vec<PathBuf>,
    /// Where the photo matches go (PNG side by side: photo | match).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Skip the recovery part.
    #[arg(long)]
    no_recovery: bool,
    /// Print every trial that is not recovered: truth, match and both
    /// objectives.
    #[arg(long)]
    verbose: bool,
}

pub fn run(a: &MatchArgs) -> Result<()> {
    let t = Instant::now();
    let cat = Catalogue::build(
        &BuildSettings {
            size: a.size,
            samples: a.samples,
            shaders: None,
        },
        &texsyn::progress::Silent,
    )?;
    println!(
        "catalogue: {} shaders × {} samples at {}² in {:.1} s ({} threads)",
        cat.shaders.len(),
        a.samples,
        a.size,
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads()
    );
    let settings = MatchSettings::default();
    if !a.no_recovery {
        println!(
            "\nrecovery, {} draws per shader (shader known), tolerance 5% of each range:",
            a.draws
        );
        println!(
            "shader      recovered  integers exact  mean s/target  max s  worst error (median)"
        );
        let (mut all_ok, mut all_n, mut all_t) = (0, 0, 0.0);
        for shader in LIBRARY {
            if !a.shaders.is_empty() && !a.shaders.iter().any(|s| s == shader.name) {
                continue;
            }
            let trials = recovery_trials(shader, a.draws, a.seed, &cat, &settings, 0.05)?;
            let ok = trials.iter().filter(|t| t.recovered).count();
            if a.verbose {
                for t in trials.iter().filter(|t| !t.recovered) {
                    println!(
                        "  missed: truth {:?} (objective {:.4})\n          found {:?} (objective {:.4}, worst error {:.3}, {} renders in {:.1} s)",
                        t.truth.params,
                        t.truth_objective,
                        t.found.pattern.params,
                        t.found.objective,
                        t.worst_error,
                        t.found.evaluations,
                        t.found.seconds
                    );
                }
            }
            let ints = trials
                .iter()
                .filter(|t| {
                    shader.params.iter().enumerate().all(|(i, p)| {
                        p.kind != Kind::Integer || t.truth.params[i] == t.found.pattern.params[i]
                    })
                })
                .count();
            let times: Vec<f64> = trials.iter().map(|t| t.found.seconds).collect();
            let mean = times.iter().sum::<f64>() / times.len().max(1) as f64;
            let max = times.iter().cloned().fold(0.0, f64::max);
            let mut errs: Vec<f64> = trials.iter().map(|t| t.worst_error).collect();
            errs.sort_by(f64::total_cmp);
            println!(
                "{:<11} {:>3}/{:<5}  {:>3}/{:<10}  {:>12.1}  {:>5.1}  {:.3}",
                shader.name,
                ok,
                trials.len(),
                ints,
                trials.len(),
                mean,
                max,
                errs.get(errs.len() / 2).copied().unwrap_or(0.0)
            );
            all_ok += ok;
            all_n += trials.len();
            all_t += times.iter().sum::<f64>();
        }
        println!(
            "all: {all_ok}/{all_n} recovered, {:.1} s per target on average",
            all_t / all_n.max(1) as f64
        );
    }
    if !a.photos.is_empty() {
        println!("\nphotos, every shader:");
        println!(
            "photo                          shader      S_F    S_L    colour  iterations  seconds"
        );
        for p in &a.photos {
            let img = imaging::load_color(p)?;
            let m = match_texture(&img, &cat, &settings)?;
            let name = p
                .file_name()
                .and_then(|n| n.to_str())
                .context("photo name")?;
            println!(
                "{:<30} {:<11} {:.3}  {:.3}  {:.3}   {:>10}  {:>7.1}",
                name, m.pattern.shader.name, m.s_f, m.s_l, m.colour, m.iterations, m.seconds
            );
            println!("    {}", m.pattern.to_json());
            if let Some(dir) = &a.out {
                std::fs::create_dir_all(dir)?;
                let r = m.pattern.render(img.width, img.height);
                let mut both = texsyn::imaging::ColorImage::from_vec(
                    2 * img.width + 8,
                    img.height,
                    vec![255; (2 * img.width + 8) * img.height * 3],
                );
                for y in 0..img.height {
                    for x in 0..img.width {
                        both.set(x, y, img.get(x, y));
                        both.set(img.width + 8 + x, y, r.get(x, y));
                    }
                }
                imaging::save_color(&dir.join(name), &both)?;
            }
        }
    }
    Ok(())
}
