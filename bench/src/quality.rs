//! `texsyn-bench quality` (ARCHITECTURE §8): every method over a list of
//! textures at twice the sample's side, each run its own `texsyn` process
//! (wall time and peak memory from `wait4`), every output measured by
//! `texsyn compare`'s figures, a JSON table and a contact sheet: per texture
//! the sample, then each method's output, labelled with its copy and repeat
//! shares.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use serde::Serialize;
use texsyn::compare::{self, set::SetScores, Grid, Scores};
use texsyn::imaging::volume::{Axis, Volume};
use texsyn::imaging::{self, ColorImage};

use crate::sheet::Sheet;

/// The methods, in the sheet's column order.
pub const METHODS: [&str; 9] = [
    "block",
    "parallel-reduced",
    "parallel-half",
    "parallel-5",
    "parallel-7",
    "somol",
    "omega",
    "morph",
    "solid",
];

/// Methods run only when named: the block method's variants and Embark's
/// `texture-synthesis` (the peer; `cargo install texture-synthesis-cli
/// --locked`), for the block method's comparison.
pub const EXTRA_METHODS: [&str; 7] = [
    "block-scanline",
    "block-hard",
    "block-path",
    "block-repeat",
    "block-seam",
    "block-cap",
    "embark",
];

#[derive(Args, Debug)]
pub struct QualityArgs {
    /// Textures: PNG files or directories of them (default: the repository's
    /// assets/textures and ../shared/textures). Masks, photos with a hole mask
    /// beside them and the height, normal and roughness maps of a material are
    /// skipped; a name seen twice once.
    pub inputs: Vec<PathBuf>,
    /// Methods to run, of: block, parallel-reduced, parallel-half,
    /// parallel-5, parallel-7, somol, omega, morph, solid; and, only when
    /// named, block-scanline, block-hard and block-path (the two stitches;
    /// `synth`'s default is path), block-repeat (repetition control at 25%),
    /// block-seam (repetition control with the seam filter, 25%, N = 13),
    /// block-cap (the patch cap at 25% of the side on the two finest levels,
    /// near-ties within 60%, N = 13) and embark (Embark's texture-synthesis, the peer).
    #[arg(long, value_delimiter = ',', default_values_t = METHODS.map(String::from))]
    pub methods: Vec<String>,
    /// Skip samples whose larger side exceeds this (0 = none).
    #[arg(long, default_value_t = 0)]
    pub max_side: usize,
    /// Edge of the solids (the faces are compared with the sample).
    #[arg(long, default_value_t = 64)]
    pub solid_size: usize,
    /// Threads of each run (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Output directory: quality.json, sheet.png and every output.
    #[arg(short, long, default_value = "quality")]
    pub out: PathBuf,
    /// Side of a picture on the contact sheet.
    #[arg(long, default_value_t = 160)]
    pub cell: usize,
    /// The texsyn binary (default: next to texsyn-bench).
    #[arg(long)]
    pub texsyn: Option<PathBuf>,
}

/// One method's run on one texture.
#[derive(Serialize)]
struct Row {
    texture: String,
    method: String,
    width: usize,
    height: usize,
    seconds: f64,
    peak_mib: f64,
    /// `compare` of the output (morph: its middle third; solid: the mean
    /// over its three faces at 0) against the sample.
    scores: Scores,
    /// Tile methods: the set's own measures.
    #[serde(skip_serializing_if = "Option::is_none")]
    set: Option<SetScores>,
}

/// A failed run, kept in the table.
#[derive(Serialize)]
struct Failure {
    texture: String,
    method: String,
    error: String,
}

#[derive(Serialize)]
struct Table {
    rows: Vec<Row>,
    failures: Vec<Failure>,
}

/// The texture files of `inputs`.
fn textures(inputs: &[PathBuf], max_side: usize) -> Result<Vec<PathBuf>> {
    let defaults = || {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .unwrap_or(Path::new("."))
            .to_path_buf();
        vec![
            root.join("assets/textures"),
            root.join("../shared/textures"),
        ]
    };
    let dirs = if inputs.is_empty() {
        defaults()
    } else {
        inputs.to_vec()
    };
    let mut files: Vec<PathBuf> = Vec::new();
    for d in dirs {
        let mut here: Vec<PathBuf> = if d.is_dir() {
            std::fs::read_dir(&d)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "png"))
                .collect()
        } else if d.is_file() {
            vec![d.clone()]
        } else if inputs.is_empty() {
            continue;
        } else {
            bail!("{} is neither a texture nor a directory", d.display());
        };
        here.sort();
        for p in here {
            let name = p
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            let skip = ["_mask_", "_height_", "_normal_", "_roughness_"]
                .iter()
                .any(|k| name.contains(k));
            let seen = files.iter().any(|f| f.file_name() == p.file_name());
            // A photo with a hole mask beside it is a fill case, not a texture.
            let fill_case = p.with_file_name(name.replace("_color_", "_mask_")) != p
                && p.with_file_name(name.replace("_color_", "_mask_"))
                    .is_file();
            if skip || seen || fill_case {
                continue;
            }
            if max_side > 0 {
                let (w, h) = image::image_dimensions(&p)
                    .with_context(|| format!("cannot read {}", p.display()))?;
                if w.max(h) as usize > max_side {
                    continue;
                }
            }
            files.push(p);
        }
    }
    ensure!(
        !files.is_empty(),
        "no textures found: give PNG files or directories"
    );
    Ok(files)
}

/// What one run needs.
struct Job<'a> {
    texsyn: &'a Path,
    threads: Option<usize>,
    sample: &'a Path,
    image: &'a ColorImage,
    /// Another texture, the far end of a morph.
    other: &'a Path,
    dir: PathBuf,
    solid_size: usize,
}

impl Job<'_> {
    /// A `texsyn` command whose output goes to `log.txt` in the run's
    /// directory.
    fn texsyn(&self, args: &[&str]) -> Result<(f64, u64)> {
        let log = std::fs::File::create(self.dir.join("log.txt"))?;
        let mut m = crate::cases::measured(self.texsyn)?;
        m.cmd
            .args(args)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log);
        if let Some(t) = self.threads {
            m.cmd.args(["--threads", &t.to_string()]);
        }
        m.run()
    }

    /// Embark's `texture-synthesis generate` of `sample` at `size` into
    /// `out`, with the same threads; its log in `log.txt`.
    fn peer(&self, sample: &str, out: &str, size: &str) -> Result<(f64, u64)> {
        let log = std::fs::File::create(self.dir.join("log.txt"))?;
        let mut m = crate::cases::measured(Path::new("texture-synthesis"))?;
        m.cmd
            .args(["--out-size", size, "--no-progress", "--out", out]);
        if let Some(t) = self.threads {
            m.cmd.args(["--threads", &t.to_string()]);
        }
        m.cmd
            .args(["generate", sample])
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log);
        m.run().context(
            "texture-synthesis failed or is not installed (cargo install texture-synthesis-cli --locked)",
        )
    }

    fn path(&self, name: &str) -> String {
        self.dir.join(name).display().to_string()
    }

    /// Runs `method`: its picture for the sheet, its scores, the set's
    /// measures, time and peak bytes.
    fn run(&self, method: &str) -> Result<(ColorImage, Scores, Option<SetScores>, f64, u64)> {
        std::fs::create_dir_all(&self.dir)?;
        let (w, h) = (self.image.width, self.image.height);
        let sample = self.sample.display().to_string();
        let size = format!("{}x{}", 2 * w, 2 * h);
        let out = self.path("out.png");
        let tile = (w.min(h) / 2) & !1;
        match method {
            "block" | "block-scanline" | "block-hard" | "block-path" | "block-repeat"
            | "block-seam" | "block-cap" => {
                let mut args = vec!["synth", &sample, "-o", &out, "--size", &size];
                match method {
                    "block-scanline" => args.extend(["--method", "scanline"]),
                    "block-hard" => args.extend(["--stitch", "hard"]),
                    "block-path" => args.extend(["--stitch", "path"]),
                    "block-repeat" => args.extend(["--repeat-percent", "25"]),
                    "block-seam" => args.extend(["--repeat-seam", "25", "--neighbourhood", "13"]),
                    "block-cap" => args.extend(["--repeat-cap", "25", "--neighbourhood", "13"]),
                    _ => {}
                }
                let (t, m) = self.texsyn(&args)?;
                let img = imaging::load_color(Path::new(&out))?;
                Ok((img.clone(), compare::compare(self.image, &img)?, None, t, m))
            }
            "embark" => {
                let (t, m) = self.peer(&sample, &out, &size)?;
                let img = imaging::load_color(Path::new(&out))?;
                Ok((img.clone(), compare::compare(self.image, &img)?, None, t, m))
            }
            m if m.starts_with("parallel-") => {
                let nb = &m["parallel-".len()..];
                let (t, mem) = self.texsyn(&[
                    "synth",
                    &sample,
                    "--method",
                    "parallel",
                    "--neighbourhood",
                    nb,
                    "-o",
                    &out,
                    "--size",
                    &size,
                ])?;
                let img = imaging::load_color(Path::new(&out))?;
                Ok((
                    img.clone(),
                    compare::compare(self.image, &img)?,
                    None,
                    t,
                    mem,
                ))
            }
            "somol" | "omega" => {
                let set = self.path("set");
                let tile_s = tile.to_string();
                let mut args = vec!["tiles", "make", &sample, "-o", &set, "--tile-size", &tile_s];
                if method == "omega" {
                    args.extend(["--method", "omega"]);
                }
                let (t, mem) = self.texsyn(&args)?;
                let sets = compare::set::set_scores(Path::new(&set))?;
                let status = Command::new(self.texsyn)
                    .args(["tiles", "assemble", &set, "--grid", "8x8", "-o", &out])
                    .stdout(Stdio::null())
                    .status()?;
                ensure!(status.success(), "texsyn tiles assemble failed ({status})");
                let img = imaging::load_color(Path::new(&out))?;
                let (tw, th) = (img.width / 8, img.height / 8);
                let grid = Grid {
                    tile_width: tw,
                    tile_height: th,
                    wrap: method == "somol",
                };
                let s = compare::compare_with(self.image, &img, Some(grid))?;
                Ok((img, s, Some(sets), t, mem))
            }
            "morph" => {
                let other = self.other.display().to_string();
                let (t, mem) = self.texsyn(&[
                    "morph", &sample, &other, "--ramp", "x", "-o", &out, "--size", &size,
                ])?;
                let img = imaging::load_color(Path::new(&out))?;
                let middle = img.crop(img.width / 3, 0, img.width / 3, img.height);
                Ok((img, compare::compare(self.image, &middle)?, None, t, mem))
            }
            "solid" => {
                let dir = self.path("solid");
                let view = format!("xyz={sample}");
                let n = self.solid_size.to_string();
                let (t, mem) = self.texsyn(&[
                    "solid", "--view", &view, "--size", &n, "--slices", "none", "-o", &dir,
                ])?;
                let (v, _) = Volume::load(&Path::new(&dir).join("solid.json"))?;
                let faces: Vec<ColorImage> = Axis::ALL.iter().map(|&a| v.slice_rgb(a, 0)).collect();
                let scores = faces
                    .iter()
                    .map(|f| compare::compare(self.image, f))
                    .collect::<Result<Vec<_>>>()?;
                Ok((faces[2].clone(), mean_scores(scores), None, t, mem))
            }
            other => bail!(
                "unknown method '{other}': give one of {}",
                METHODS.join(", ")
            ),
        }
    }
}

/// The mean of each figure over `all` (the first one's seam offset and tiles).
fn mean_scores(all: Vec<Scores>) -> Scores {
    let n = all.len().max(1) as f64;
    let mean = |f: fn(&Scores) -> f64| all.iter().map(f).sum::<f64>() / n;
    let mut s = all[0].clone();
    s.s_f = mean(|s| s.s_f);
    s.s_l = mean(|s| s.s_l);
    s.colour = mean(|s| s.colour);
    s.patch_fidelity = mean(|s| s.patch_fidelity);
    s.copy_share = mean(|s| s.copy_share);
    s.repeat_share = mean(|s| s.repeat_share);
    s.seam.ratio = mean(|s| s.seam.ratio);
    s.seam.beside_ratio = mean(|s| s.seam.beside_ratio);
    s
}

pub fn run(a: &QualityArgs) -> Result<()> {
    for m in &a.methods {
        ensure!(
            METHODS.contains(&m.as_str()) || EXTRA_METHODS.contains(&m.as_str()),
            "unknown method '{m}': give some of {}, {}",
            METHODS.join(", "),
            EXTRA_METHODS.join(", ")
        );
    }
    let texsyn = crate::cases::sibling_binary("texsyn", a.texsyn.as_deref(), "--texsyn")?;
    let files = textures(&a.inputs, a.max_side)?;
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    let mut sheet = Sheet::new(a.cell, 1 + a.methods.len());
    let mut table = Table {
        rows: Vec::new(),
        failures: Vec::new(),
    };
    println!("| texture | method | time | peak | S_F | S_L | colour | fidelity | copy | repeat | seam (joint / beside) | overlap (chance) / nearest pair / joint offset |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for (k, file) in files.iter().enumerate() {
        let name = file
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        let image = imaging::load_color(file)?;
        let mut cells = vec![(
            image.clone(),
            format!("{name}\n{}x{}", image.width, image.height),
        )];
        for method in &a.methods {
            let job = Job {
                texsyn: &texsyn,
                threads: a.threads,
                sample: file,
                image: &image,
                other: &files[(k + 1) % files.len()],
                dir: a.out.join(&name).join(method),
                solid_size: a.solid_size,
            };
            match job.run(method) {
                Ok((img, scores, set, secs, peak)) => {
                    let overlap = scores.tiles.as_ref().map_or("-".into(), |t| {
                        format!(
                            "{:.3} ({:.3}) / {} / {:.2}",
                            t.tile_overlap,
                            t.tile_overlap_chance,
                            t.tile_copy.map_or("-".into(), |c| format!("{c:.2}")),
                            t.joint_offset
                        )
                    });
                    println!(
                        "| {name} | {method} | {secs:.1} s | {:.0} MiB | {:.3} | {:.3} | {:.4} | {:.2} | {:.3} | {:.3} | {:.2} / {:.2} | {overlap} |",
                        peak as f64 / 1048576.0,
                        scores.s_f,
                        scores.s_l,
                        scores.colour,
                        scores.patch_fidelity,
                        scores.copy_share,
                        scores.repeat_share,
                        scores.seam.ratio,
                        scores.seam.beside_ratio
                    );
                    cells.push((
                        img,
                        format!(
                            "{method}\ncopy {:.2} rep {:.2}",
                            scores.copy_share, scores.repeat_share
                        ),
                    ));
                    table.rows.push(Row {
                        texture: name.clone(),
                        method: method.clone(),
                        width: 2 * image.width,
                        height: 2 * image.height,
                        seconds: secs,
                        peak_mib: peak as f64 / 1048576.0,
                        scores,
                        set,
                    });
                }
                Err(e) => {
                    println!("| {name} | {method} | failed: {e:#} |");
                    cells.push((ColorImage::new(1, 1), format!("{method}\nfailed")));
                    table.failures.push(Failure {
                        texture: name.clone(),
                        method: method.clone(),
                        error: format!("{e:#}"),
                    });
                }
            }
        }
        sheet.add_row(&cells);
        // Written after every texture, so a long run can be looked at early.
        imaging::save_color(&a.out.join("sheet.png"), &sheet.image())?;
        imaging::save_bytes(
            &a.out.join("quality.json"),
            &serde_json::to_vec_pretty(&table)?,
        )?;
    }
    eprintln!(
        "wrote {} and {}",
        a.out.join("quality.json").display(),
        a.out.join("sheet.png").display()
    );
    Ok(())
}
