//! `texsyn-bench match`: the figures of procedural matching (ARCHITECTURE
//! §12): the catalogue's build time, recovery of synthetic targets per
//! shader (10 random draws each, the criterion: every continuous
//! parameter and colour channel within 5% of its range, whole numbers
//! exact), match time per target, and matches of photos with their scores.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use texsyn::imaging::{self, ColorImage};
use texsyn::procedural::catalogue::{BuildSettings, Catalogue};
use texsyn::procedural::labels;
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
    /// A label file (see `texsyn::procedural::labels`): its photos, in its
    /// directory, are matched and judged (family, count within 15%).
    #[arg(long)]
    labels: Option<PathBuf>,
    /// Where the photo matches go (PNG side by side: photo | match; with
    /// --labels also sheet.png, every labelled photo | its match).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Skip the recovery part.
    #[arg(long)]
    no_recovery: bool,
    /// With --labels: print each photo's arrangement and its measures, and
    /// match nothing.
    #[arg(long)]
    arrangement_only: bool,
    /// Print every trial that is not recovered: truth, match and both
    /// objectives.
    #[arg(long)]
    verbose: bool,
}

pub fn run(a: &MatchArgs) -> Result<()> {
    if let (true, Some(l)) = (a.arrangement_only, &a.labels) {
        return arrangements(l, a.size);
    }
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
    if let Some(l) = &a.labels {
        labelled(l, &cat, &settings, a.out.as_deref())?;
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

/// `photo` and `other` side by side, 8 white pixels apart, both at
/// `side`² (nearest neighbour, so small photos stay sharp).
fn pair(photo: &ColorImage, other: &ColorImage, side: usize) -> ColorImage {
    let mut out = ColorImage::from_vec(2 * side + 8, side, vec![255; (2 * side + 8) * side * 3]);
    for (img, x0) in [(photo, 0), (other, side + 8)] {
        for y in 0..side {
            for x in 0..side {
                out.set(
                    x0 + x,
                    y,
                    img.get(x * img.width / side, y * img.height / side),
                );
            }
        }
    }
    out
}

/// The labelled photos matched and judged: family and count per photo,
/// time per photo, the tally, and the sheet.
fn labelled(
    file: &std::path::Path,
    cat: &Catalogue,
    settings: &MatchSettings,
    out: Option<&std::path::Path>,
) -> Result<()> {
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("cannot read the labels {}", file.display()))?;
    let list = labels::parse(&text)?;
    let dir = file.parent().unwrap_or(std::path::Path::new("."));
    println!("\nlabelled photos ({}), every shader:", file.display());
    println!(
        "photo                          want                 count   arrangement  found        count  error  right  seconds  cpu-s"
    );
    let (mut right, mut family, mut secs) = (0, 0, Vec::new());
    let mut rows = Vec::new();
    for l in &list {
        let img = imaging::load_color(&dir.join(&l.file))?;
        let cpu = cpu_seconds();
        let m = match_texture(&img, cat, settings)?;
        let cpu = cpu_seconds() - cpu;
        let v = labels::check(l, &m.pattern);
        let (_, a) = texsyn::procedural::objective::periodicity_of(
            &texsyn::procedural::analysis_image(&img, cat.size),
        );
        right += usize::from(v.right);
        family += usize::from(v.family_right);
        secs.push(m.seconds);
        let num = |x: Option<f64>| x.map_or("-".to_string(), |c| format!("{c:.1}"));
        println!(
            "{:<30} {:<20} {:>5}   {:<11}  {:<12} {:>5}  {:>5}  {:<5}  {:>7.1}  {:>5.1}",
            l.file,
            l.families.join("|"),
            num(l.count),
            a.arrangement.name(),
            m.pattern.shader.name,
            num(v.count),
            v.count_error
                .map_or("-".to_string(), |e| format!("{:.0}%", 100.0 * e)),
            if v.right { "yes" } else { "no" },
            m.seconds,
            cpu
        );
        println!("    {}", m.pattern.to_json());
        rows.push(pair(&img, &m.pattern.render(img.width, img.height), 128));
    }
    secs.sort_by(f64::total_cmp);
    println!(
        "right {right}/{} (family {family}/{}), seconds per photo {:.1}–{:.1}, median {:.1}",
        list.len(),
        list.len(),
        secs.first().copied().unwrap_or(0.0),
        secs.last().copied().unwrap_or(0.0),
        secs.get(secs.len() / 2).copied().unwrap_or(0.0)
    );
    if let (Some(dir), Some(first)) = (out, rows.first()) {
        std::fs::create_dir_all(dir)?;
        let (w, h) = (first.width, first.height + 4);
        let cols = 2;
        let n = rows.len().div_ceil(cols);
        let mut sheet = ColorImage::from_vec(
            cols * (w + 12),
            n * h,
            vec![255; cols * (w + 12) * n * h * 3],
        );
        for (i, r) in rows.iter().enumerate() {
            let (x0, y0) = ((i % cols) * (w + 12), (i / cols) * h);
            for y in 0..r.height {
                for x in 0..r.width {
                    sheet.set(x0 + x, y0 + y, r.get(x, y));
                }
            }
        }
        imaging::save_color(&dir.join("sheet.png"), &sheet)?;
        println!("sheet: {}", dir.join("sheet.png").display());
    }
    Ok(())
}

/// Each labelled photo's arrangement and the measures it was decided from.
fn arrangements(file: &std::path::Path, size: usize) -> Result<()> {
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("cannot read the labels {}", file.display()))?;
    let dir = file.parent().unwrap_or(std::path::Path::new("."));
    println!("photo                          want                 arrangement  orient  second  lattice  frequency  separation  pieces  radial");
    for l in labels::parse(&text)? {
        let img = imaging::load_color(&dir.join(&l.file))?;
        let (per, a) = texsyn::procedural::objective::periodicity_of(
            &texsyn::procedural::analysis_image(&img, size),
        );
        println!(
            "{:<30} {:<20} {:<11}  {:>6.2}  {:>6.2}  {:>7.2}  {:>9.1}  {:>10.2}  {:>6.1}  {:>6.1}",
            l.file,
            l.families.join("|"),
            a.arrangement.name(),
            a.orientation,
            a.second,
            a.lattice,
            per.scale,
            per.pieces.separation,
            per.pieces.count,
            if per.radial.period > 0.0 {
                per.size as f64 / per.radial.period
            } else {
                0.0
            }
        );
    }
    Ok(())
}

/// CPU seconds of this process so far (user + system), 0 where unknown.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the command's closing parenthesis: utime is the 12th.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}
