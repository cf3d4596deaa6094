//! `texsyn tiles make|assemble`.

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::imaging::{self, ColorImage};
use crate::tiles::{self, PathSearch, TileSetSettings};

#[derive(Subcommand, Debug)]
pub enum TilesCommand {
    /// Make a set of tiles that all connect to each other (Somol–Haindl).
    #[command(
        after_help = "Example: texsyn tiles make sample.png --method somol --tiles 8 --tile-size 128 -o tiles/"
    )]
    Make(Box<MakeArgs>),
    /// Lay a tile set out in a grid, by an index matrix or at random.
    #[command(
        after_help = "Example: texsyn tiles assemble tiles/ --grid 8x8 --seed 3 -o wall.png"
    )]
    Assemble(AssembleArgs),
}

#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum TileMethod {
    /// Template tile plus patched copies (Somol and Haindl).
    Somol,
    /// ω-tiles from sample patches chosen by an immune search (Dong, Zhou and
    /// Paul).
    Omega,
}

#[derive(Args, Debug)]
pub struct MakeArgs {
    /// The sample image.
    pub sample: PathBuf,
    /// Output directory (created): tile_NN.png, atlas.png, tileset.json.
    #[arg(short, long)]
    pub output: PathBuf,
    #[arg(long, value_enum, default_value_t = TileMethod::Somol)]
    pub method: TileMethod,
    /// Number of tiles, the template included.
    #[arg(long, default_value_t = 8)]
    pub tiles: usize,
    /// Tile side: the template's size is searched in [0.8·S, S] (default: half
    /// the sample's smaller side, at most 256).
    #[arg(long)]
    pub tile_size: Option<usize>,
    /// Overlap of the template's stitches and belt of the patches (default:
    /// a tenth of the tile, as in the paper).
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Use this seamless tile as the template instead of searching one (e.g.
    /// the output of `texsyn extend --tileable`).
    #[arg(long)]
    pub template: Option<PathBuf>,
    /// Random candidate patch positions per tile.
    #[arg(long, default_value_t = 48)]
    pub candidates: usize,
    /// How each stitch finds its path: the oscillating search, or the exact
    /// optimum (slower at wide overlaps).
    #[arg(long, value_enum, default_value_t = PathSearch::Oscillating)]
    pub path: PathSearch,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// ω-tiles: the set, 8 (4 patches), 17 (5) or 38 (6).
    #[arg(long, default_value_t = 38)]
    pub set: usize,
    /// ω-tiles: antibodies in the immune search (N_p).
    #[arg(long, default_value_t = 40)]
    pub population: usize,
    /// ω-tiles: generations at most (N_g).
    #[arg(long, default_value_t = 50)]
    pub generations: usize,
    /// ω-tiles: stop after this many generations without improvement (N_o;
    /// 0 = never, run all N_g).
    #[arg(long, default_value_t = 6)]
    pub patience: usize,
    /// ω-tiles: random patch sets whose affinity `ais.json` reports beside the
    /// search's (0 = none).
    #[arg(long, default_value_t = 100)]
    pub baseline: usize,
    /// Search threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    #[command(flatten)]
    pub cluster: super::ClusterArgs,
    /// No progress bar.
    #[arg(short, long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct AssembleArgs {
    /// A directory written by `texsyn tiles make`.
    pub dir: PathBuf,
    /// Grid size in tiles, COLSxROWS (ignored with --index).
    #[arg(long, default_value = "4x4")]
    pub grid: String,
    /// Index matrix: CSV (one row per line) or JSON (an array of rows) of tile
    /// numbers from 1.
    #[arg(long)]
    pub index: Option<PathBuf>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[arg(short, long)]
    pub output: PathBuf,
}

#[derive(Serialize)]
struct TileSetFile<'a> {
    method: &'static str,
    sample: String,
    tile_width: usize,
    tile_height: usize,
    settings: &'a TileSetSettings,
    template: &'a tiles::tileset::TemplateChoice,
    template_given: bool,
    template_path_costs: [f64; 2],
    template_seconds: f64,
    tiles: Vec<TileEntry<'a>>,
    seconds: f64,
}

#[derive(Serialize)]
struct TileEntry<'a> {
    number: usize,
    file: String,
    derived: Option<&'a tiles::tileset::DerivedTile>,
}

pub fn run(cmd: TilesCommand) -> Result<()> {
    match cmd {
        TilesCommand::Make(a) => make(&a),
        TilesCommand::Assemble(a) => assemble(&a),
    }
}

fn tile_path(dir: &Path, n: usize) -> PathBuf {
    dir.join(format!("tile_{n:02}.png"))
}

/// A bar of `len` steps counted in `unit`, none with `--quiet`.
fn progress_bar(quiet: bool, len: usize, unit: &str, message: &'static str) -> Option<ProgressBar> {
    (!quiet).then(|| {
        let b = ProgressBar::new(len as u64);
        let template = format!("{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit} {{elapsed}}");
        b.set_style(
            ProgressStyle::with_template(&template)
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        b.set_message(message);
        b
    })
}

/// The counts of `tiles make` within their ranges, checked before any work.
fn check_counts(a: &MakeArgs) -> Result<()> {
    let within = |v: usize, lo: usize, hi: usize, flag: &str| {
        ensure!(
            (lo..=hi).contains(&v),
            "{flag} {v} is out of range: give {lo}..={hi}"
        );
        Ok(())
    };
    within(a.candidates, 1, 10_000, "--candidates")?;
    within(a.population, 2, 1_000, "--population")?;
    within(a.generations, 1, 10_000, "--generations")?;
    within(a.patience, 0, 10_000, "--patience")?;
    within(a.baseline, 0, 10_000, "--baseline")?;
    if let Some(o) = a.overlap {
        within(o, 1, 1 << 14, "--overlap")?;
    }
    if let Some(t) = a.tile_size {
        within(t, 4, 1 << 14, "--tile-size")?;
    }
    Ok(())
}

fn make(a: &MakeArgs) -> Result<()> {
    check_counts(a)?;
    let pool = super::thread_pool(a.threads)?;
    if matches!(a.method, TileMethod::Omega) {
        return pool.install(|| make_omega(a));
    }
    pool.install(|| make_somol(a))
}

fn make_somol(a: &MakeArgs) -> Result<()> {
    ensure!(
        (1..=99).contains(&a.tiles),
        "--tiles {} is out of range: give 1..=99",
        a.tiles
    );
    let started = std::time::Instant::now();
    let sample = imaging::load_color(&a.sample)?;
    let template = a.template.as_deref().map(imaging::load_color).transpose()?;
    let size = match (&template, a.tile_size) {
        (Some(t), _) => t.width.min(t.height),
        (None, Some(s)) => s,
        (None, None) => (sample.width.min(sample.height) / 2).min(256),
    };
    let overlap = a.overlap.unwrap_or((size / 10).max(2));
    ensure!(
        2 * overlap < size,
        "--overlap {overlap} must be under half the {size}-pixel tile: give a smaller --overlap or a larger --tile-size"
    );
    let settings = TileSetSettings {
        tiles: a.tiles,
        min_size: (size * 4 / 5).max(2 * overlap + 1),
        max_size: size,
        overlap,
        belt: overlap,
        margin: 2,
        candidates: a.candidates.max(1),
        refine: 4,
        path: a.path,
        seed: a.seed,
    };
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("cannot create the output directory {}", a.output.display()))?;
    let bar = progress_bar(a.quiet, a.tiles, "tiles", "tiles");
    let set = tiles::make_tile_set(&sample, template.as_ref(), &settings, &|k| {
        if let Some(b) = &bar {
            b.set_position(k as u64);
        }
        tracing::info!(tile = k, "tile done");
    })?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut entries = Vec::new();
    for (k, t) in set.tiles.iter().enumerate() {
        let path = tile_path(&a.output, k + 1);
        imaging::save_color(&path, t)?;
        entries.push(TileEntry {
            number: k + 1,
            file: path.file_name().unwrap().to_string_lossy().into_owned(),
            derived: k.checked_sub(1).map(|d| &set.derived[d]),
        });
    }
    // The atlas: all tiles in one row.
    let index = vec![(1..=set.tiles.len()).collect::<Vec<_>>()];
    imaging::save_color(
        &a.output.join("atlas.png"),
        &tiles::assemble(&set.tiles, &index)?,
    )?;
    let (tw, th) = (set.tiles[0].width, set.tiles[0].height);
    let file = TileSetFile {
        method: "somol",
        sample: a.sample.display().to_string(),
        tile_width: tw,
        tile_height: th,
        settings: &settings,
        template: &set.template,
        template_given: template.is_some(),
        template_path_costs: set.template_path_costs,
        template_seconds: set.template_seconds,
        tiles: entries,
        seconds: started.elapsed().as_secs_f64(),
    };
    let json = serde_json::to_vec_pretty(&file)?;
    imaging::save_bytes(&a.output.join("tileset.json"), &json)?;
    if !a.quiet {
        eprintln!(
            "wrote {} tiles of {tw}×{th} to {} ({:.2} s)",
            set.tiles.len(),
            a.output.display(),
            file.seconds
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct OmegaSetFile<'a> {
    method: &'static str,
    sample: String,
    tile_width: usize,
    tile_height: usize,
    /// Corner colours of each tile (top-left, top-right, bottom-left,
    /// bottom-right), e.g. "BYYR".
    set: Vec<String>,
    /// The sample patch of each colour (top-left corner), R, G, B, Y, C, M.
    patches: &'a [tiles::ais::Gene],
    tiles: Vec<OmegaEntry<'a>>,
    search_seconds: f64,
    build_seconds: f64,
    seconds: f64,
}

#[derive(Serialize)]
struct OmegaEntry<'a> {
    number: usize,
    file: String,
    #[serde(flatten)]
    tile: &'a tiles::ais::OmegaTile,
}

#[derive(Serialize)]
struct AisFile<'a> {
    settings: &'a tiles::ais::AisSettings,
    evaluation_steps: usize,
    evaluation_side: usize,
    result: &'a tiles::ais::AisResult,
    random_mean_f: Option<f64>,
    random_best_f: Option<f64>,
    random_sets: usize,
}

fn make_omega(a: &MakeArgs) -> Result<()> {
    use tiles::ais;
    let started = std::time::Instant::now();
    ensure!(
        a.template.is_none(),
        "--template belongs to --method somol; ω-tiles are built from sample patches"
    );
    let set = tiles::omega::OmegaSet::of_size(a.set)?;
    let sample = imaging::load_color(&a.sample)?;
    let size = a
        .tile_size
        .unwrap_or((sample.width.min(sample.height) * 5 / 8) & !1);
    let mut evaluator = ais::Evaluator::new(&set, &sample, size)?;
    let engine = texsyn_engine::Engine::default();
    let cluster = a.cluster.setup()?;
    let (options, _local_workers, _ssh_workers) = match cluster {
        Some(c) => (Some(c.options), c.local, c.ssh),
        None => (None, None, None),
    };
    let mut backend: Box<dyn crate::search::SearchBackend> = match options {
        Some(o) => Box::new(crate::cluster::ClusterSearch::connect(o, engine)?),
        None => Box::new(crate::search::LocalSearch::new(engine)),
    };
    evaluator.load(backend.as_mut())?;
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("cannot create the output directory {}", a.output.display()))?;
    let settings = ais::AisSettings {
        population: a.population.max(2),
        generations: a.generations.max(1),
        patience: if a.patience == 0 {
            usize::MAX
        } else {
            a.patience
        },
        seed: a.seed,
        ..ais::AisSettings::default()
    };
    let bar = progress_bar(
        a.quiet,
        settings.generations,
        "generations",
        "immune search",
    );
    let result = ais::search(&mut evaluator, backend.as_mut(), &sample, &settings, &|g| {
        if let Some(b) = &bar {
            b.set_position(g.generation as u64);
        }
        tracing::info!(
            generation = g.generation,
            best_f = g.best_f,
            "generation done"
        );
    })?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let random = if a.baseline > 0 {
        ais::random_affinities(
            &mut evaluator,
            backend.as_mut(),
            &sample,
            a.baseline,
            settings.lambda,
            a.seed ^ 0x5eed,
        )?
    } else {
        Vec::new()
    };
    let t = std::time::Instant::now();
    let (images, built) = ais::build_tiles(&evaluator, &sample, &result.genes);
    let build_seconds = t.elapsed().as_secs_f64();
    let mut entries = Vec::new();
    for (k, (img, tile)) in images.iter().zip(&built).enumerate() {
        let path = tile_path(&a.output, k + 1);
        imaging::save_color(&path, img)?;
        entries.push(OmegaEntry {
            number: k + 1,
            file: path.file_name().unwrap().to_string_lossy().into_owned(),
            tile,
        });
    }
    let index = vec![(1..=images.len()).collect::<Vec<_>>()];
    imaging::save_color(
        &a.output.join("atlas.png"),
        &tiles::assemble(&images, &index)?,
    )?;
    let ais_file = AisFile {
        settings: &settings,
        evaluation_steps: evaluator.steps,
        evaluation_side: evaluator.side,
        result: &result,
        random_mean_f: (!random.is_empty())
            .then(|| random.iter().sum::<f64>() / random.len() as f64),
        random_best_f: random.iter().copied().reduce(f64::max),
        random_sets: random.len(),
    };
    imaging::save_bytes(
        &a.output.join("ais.json"),
        &serde_json::to_vec_pretty(&ais_file)?,
    )?;
    let file = OmegaSetFile {
        method: "omega",
        sample: a.sample.display().to_string(),
        tile_width: size,
        tile_height: size,
        set: set
            .tiles
            .iter()
            .map(|&t| tiles::omega::OmegaSet::name(t))
            .collect(),
        patches: &result.genes,
        tiles: entries,
        search_seconds: result.seconds,
        build_seconds,
        seconds: started.elapsed().as_secs_f64(),
    };
    imaging::save_bytes(
        &a.output.join("tileset.json"),
        &serde_json::to_vec_pretty(&file)?,
    )?;
    if !a.quiet {
        eprintln!(
            "wrote {} ω-tiles of {size}×{size} to {} (f = {:.4}, {:.2} s)",
            images.len(),
            a.output.display(),
            result.best_f,
            file.seconds
        );
    }
    Ok(())
}

/// The ω-tile set a `tileset.json` describes, if it describes one.
fn omega_set_of(json: &serde_json::Value) -> Result<Option<tiles::omega::OmegaSet>> {
    if json["method"] != "omega" {
        return Ok(None);
    }
    let names = json["set"]
        .as_array()
        .context("tileset.json of an ω-tile set lists no \"set\"")?;
    let tiles = names
        .iter()
        .map(|n| {
            let n = n.as_str().unwrap_or("");
            let corners: Vec<u8> = n
                .chars()
                .filter_map(|c| tiles::omega::COLOUR_NAMES.iter().position(|&k| k == c))
                .map(|k| k as u8)
                .collect();
            <[u8; 4]>::try_from(corners)
                .map_err(|_| anyhow::anyhow!("tileset.json: '{n}' is not four corner colours"))
        })
        .collect::<Result<Vec<_>>>()?;
    let colours = tiles
        .iter()
        .flatten()
        .map(|&c| usize::from(c) + 1)
        .max()
        .unwrap_or(0);
    Ok(Some(tiles::omega::OmegaSet { colours, tiles }))
}

/// Reads an index matrix: JSON (an array of arrays) or CSV (comma, semicolon
/// or whitespace separated; `#` starts a comment).
pub fn read_index(path: &Path) -> Result<Vec<Vec<usize>>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the index matrix {}", path.display()))?;
    if text.trim_start().starts_with('[') {
        return serde_json::from_str(&text).with_context(|| {
            format!(
                "{} is not a JSON array of rows of tile numbers, e.g. [[1,2],[2,1]]",
                path.display()
            )
        });
    }
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let row = line
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<usize>().with_context(|| {
                    format!(
                        "{} line {}: '{s}' is not a tile number",
                        path.display(),
                        n + 1
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        rows.push(row);
    }
    Ok(rows)
}

fn assemble(a: &AssembleArgs) -> Result<()> {
    let json = a.dir.join("tileset.json");
    ensure!(
        json.is_file(),
        "{} has no tileset.json; make one with `texsyn tiles make`",
        a.dir.display()
    );
    let mut set: Vec<ColorImage> = Vec::new();
    for n in 1.. {
        let p = tile_path(&a.dir, n);
        if !p.is_file() {
            break;
        }
        set.push(imaging::load_color(&p)?);
    }
    if set.is_empty() {
        bail!("{} holds no tile_01.png", a.dir.display());
    }
    let meta: serde_json::Value = serde_json::from_slice(&std::fs::read(&json)?)
        .with_context(|| format!("{} is not valid JSON", json.display()))?;
    let omega = omega_set_of(&meta)?;
    // The grid's size is checked before its index or image is made.
    let (tw, th) = (set[0].width, set[0].height);
    let fits = |cols: usize, rows: usize, flag: &str| -> Result<()> {
        let (w, h) = (cols.saturating_mul(tw), rows.saturating_mul(th));
        imaging::check_size(w, h, "the assembled grid")
            .with_context(|| format!("{flag}: {cols}x{rows} tiles of {tw}x{th} are too many"))?;
        imaging::check_output_size(&a.output, w, h)
    };
    if a.index.is_none() {
        let (cols, rows) = super::args::parse_pair(&a.grid, "--grid")?;
        fits(cols, rows, "--grid")?;
    }
    if let Some(o) = &omega {
        ensure!(
            o.tiles.len() == set.len(),
            "tileset.json lists {} ω-tiles but {} holds {}: the set is damaged, make it again with `texsyn tiles make`",
            o.tiles.len(),
            a.dir.display(),
            set.len()
        );
    }
    let index = match (&a.index, &omega) {
        (Some(p), _) => read_index(p)?,
        (None, Some(o)) => {
            let (cols, rows) = super::args::parse_pair(&a.grid, "--grid")?;
            tiles::omega::scan_line_tiling(o, cols, rows, a.seed)?
                .into_iter()
                .map(|r| r.into_iter().map(|k| k + 1).collect())
                .collect()
        }
        (None, None) => {
            let (cols, rows) = super::args::parse_pair(&a.grid, "--grid")?;
            tiles::random_index(set.len(), cols, rows, a.seed)
        }
    };
    if a.index.is_some() {
        fits(index.first().map_or(0, Vec::len), index.len(), "--index")?;
    }
    let in_range = index
        .iter()
        .flatten()
        .all(|&n| (1..=set.len()).contains(&n));
    if let (Some(o), Some(p), true) = (&omega, &a.index, in_range) {
        let zero: Vec<Vec<usize>> = index
            .iter()
            .map(|r| r.iter().map(|&n| n - 1).collect())
            .collect();
        ensure!(
            tiles::omega::tiling_is_valid(o, &zero),
            "{}: neighbouring ω-tiles must agree on their shared corner colours",
            p.display()
        );
    }
    let img = tiles::assemble(&set, &index)?;
    imaging::save_color(&a.output, &img)
}
