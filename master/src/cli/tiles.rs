//! `texsyn tiles make|assemble`: flags to a validated [`tiles::MakeConfig`],
//! the library run, a report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Result};
use clap::{Args, Subcommand, ValueEnum};

use super::args::parse_pair;
use super::progress::Bars;
use crate::budget::Budget;
use crate::imaging::{self, paths, OutputDir};
use crate::tiles::{
    self, Blend, Layout, MakeConfig, OmegaConfig, PathSearch, SomolConfig, TileSetFile,
};

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
    /// Output directory, replaced as a whole: tile_NN.png, atlas.png,
    /// tileset.json.
    #[arg(short, long)]
    pub output: PathBuf,
    #[arg(long, value_enum, default_value_t = TileMethod::Somol)]
    pub method: TileMethod,
    /// Number of tiles, the template included.
    #[arg(long, default_value_t = SomolConfig::default().tiles)]
    pub tiles: usize,
    /// Tile side: every tile is S×S. Without it the template's size is
    /// searched in [0.8·S, S] for S half the sample's smaller side (at most
    /// 256), as the paper chooses it.
    #[arg(long)]
    pub tile_size: Option<usize>,
    /// Overlap of the template's stitches (default: a tenth of the tile, as
    /// in the paper).
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Belt of the patch stitches (default: a tenth of the tile, at least 3,
    /// the paper's w_P = w_T; widened to three times the sample's
    /// correlation length, at most a fifth of the tile, so that paths can
    /// pass round large objects).
    #[arg(long)]
    pub belt: Option<usize>,
    /// Least pull of the patch paths towards the tile's edge, in RGB
    /// distance per pixel of the belt (0: the paper's search). Each tile
    /// doubles it while the set's mean overlap is over --max-overlap.
    #[arg(long, default_value_t = SomolConfig::default().pull)]
    pub pull: f32,
    /// Mean share of equal pixels between two tiles of the set (what
    /// `texsyn compare set/` reports as tile_overlap) that the stitch paths
    /// are pulled to keep (1: no limit, the least pull everywhere). Tiles
    /// that share less look less alike; a lower budget pulls the paths
    /// straighter.
    #[arg(long, default_value_t = SomolConfig::default().max_overlap)]
    pub max_overlap: f64,
    /// Template placements stitched and compared, at the overlap and twice it
    /// (1: the paper's single best by border error).
    #[arg(long, default_value_t = SomolConfig::default().template_candidates)]
    pub template_candidates: usize,
    /// Weight, in the template choice, of how far the template's border
    /// ring (the lines along every joint, which all tiles of the set keep)
    /// is from the sample's typical brightness, contrast and detail: each
    /// placement's path error is scaled by 1 + WEIGHT · that distance. 0:
    /// border error alone; a pale or flat border then draws the grid.
    #[arg(long, default_value_t = SomolConfig::default().template_ring)]
    pub template_ring: f64,
    /// Use this seamless tile as the template instead of searching one (e.g.
    /// the output of `texsyn extend --tileable`).
    #[arg(long)]
    pub template: Option<PathBuf>,
    /// Random candidate patch positions per tile.
    #[arg(long, default_value_t = SomolConfig::default().candidates)]
    pub candidates: usize,
    /// How each stitch finds its path: the oscillating search, or the exact
    /// optimum (slower at wide overlaps).
    #[arg(long, value_enum, default_value_t = SomolConfig::default().path)]
    pub path: PathSearch,
    /// How far from its paths a patch blends: feather (every path pixel
    /// over ρ = 3 pixels) or error (the paper's range scaled by the path
    /// pixel's error, which leaves a hard step beside the joints where the
    /// paths hug the tile's edges). The template's stitches keep the paper's.
    #[arg(long, value_enum, default_value_t = SomolConfig::default().blend)]
    pub blend: Blend,
    #[arg(long, default_value_t = SomolConfig::default().seed)]
    pub seed: u64,
    /// ω-tiles: the set, 8 (4 patches), 17 (5) or 38 (6).
    #[arg(long, default_value_t = OmegaConfig::default().set)]
    pub set: usize,
    /// ω-tiles: antibodies in the immune search (N_p).
    #[arg(long, default_value_t = OmegaConfig::default().population)]
    pub population: usize,
    /// ω-tiles: generations at most (N_g).
    #[arg(long, default_value_t = OmegaConfig::default().generations)]
    pub generations: usize,
    /// ω-tiles: stop after this many generations without improvement (N_o;
    /// 0 = never, run all N_g).
    #[arg(long, default_value_t = OmegaConfig::default().patience)]
    pub patience: usize,
    /// ω-tiles: random patch sets whose affinity `ais.json` reports beside the
    /// search's (0 = none).
    #[arg(long, default_value_t = OmegaConfig::default().baseline)]
    pub baseline: usize,
    #[command(flatten)]
    pub run: super::RunArgs,
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
    /// No summary line.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Every count is checked, whichever method uses it, so a bad flag is
/// never silently ignored.
impl TryFrom<&MakeArgs> for MakeConfig {
    type Error = anyhow::Error;

    fn try_from(a: &MakeArgs) -> Result<Self> {
        let somol = SomolConfig {
            tiles: a.tiles,
            tile_size: a.tile_size,
            overlap: a.overlap,
            belt: a.belt,
            pull: a.pull,
            max_overlap: a.max_overlap,
            template_candidates: a.template_candidates,
            template_ring: a.template_ring,
            candidates: a.candidates,
            path: a.path,
            blend: a.blend,
            seed: a.seed,
        };
        let omega = OmegaConfig {
            set: a.set,
            tile_size: a.tile_size,
            population: a.population,
            generations: a.generations,
            patience: a.patience,
            baseline: a.baseline,
            seed: a.seed,
        };
        somol.validate()?;
        omega.validate()?;
        Ok(match a.method {
            TileMethod::Somol => Self::Somol(somol),
            TileMethod::Omega => {
                ensure!(
                    a.template.is_none(),
                    "--template belongs to --method somol; ω-tiles are built from sample patches"
                );
                Self::Omega(omega)
            }
        })
    }
}

pub fn run(cmd: TilesCommand) -> Result<()> {
    match cmd {
        TilesCommand::Make(a) => make(&a),
        TilesCommand::Assemble(a) => assemble(&a),
    }
}

fn make(a: &MakeArgs) -> Result<()> {
    let config = MakeConfig::try_from(a)?;
    let pool = a.run.pool()?;
    let started = Instant::now();
    let sample = imaging::load_color(&a.sample)?;
    let name = a.sample.display().to_string();
    let mut inputs = vec![("sample", a.sample.as_path())];
    let bars = Bars::new(a.run.quiet);
    let made = match &config {
        MakeConfig::Somol(c) => {
            let template = a.template.as_deref().map(imaging::load_color).transpose()?;
            let settings = c.settings(&sample, template.as_ref())?;
            if let Some(t) = &a.template {
                inputs.push(("--template", t));
            }
            let out = OutputDir::create(&a.output, &inputs)?;
            let made = pool.install(|| {
                let sample = (&sample, name.as_str());
                tiles::make_somol(
                    &settings,
                    sample,
                    template.as_ref(),
                    out.path(),
                    &bars,
                    started,
                )
            })?;
            out.commit()?;
            made
        }
        MakeConfig::Omega(c) => {
            let set = c.omega_set()?;
            let mut evaluator = tiles::omega_evaluator(c, &set, &sample)?;
            let out = OutputDir::create(&a.output, &inputs)?;
            let made = pool.install(|| {
                let sample = (&sample, name.as_str());
                tiles::make_omega(c, &mut evaluator, sample, out.path(), &bars, started)
            })?;
            out.commit()?;
            made
        }
    };
    if !a.run.quiet {
        let kind = if made.best_f.is_some() {
            "ω-tiles"
        } else {
            "tiles"
        };
        let f = made
            .best_f
            .map(|f| format!("f = {f:.4}, "))
            .unwrap_or_default();
        eprintln!(
            "wrote {} {kind} of {}×{} to {} ({f}{:.2} s)",
            made.tiles,
            made.tile_width,
            made.tile_height,
            a.output.display(),
            made.seconds
        );
    }
    Ok(())
}

/// Refuses an output that would overwrite a file of the set in `dir` or an
/// index matrix, or land inside the set (which `tiles make` replaces whole).
fn check_output(a: &AssembleArgs, tile_paths: &[PathBuf]) -> Result<()> {
    imaging::check_writable(&a.output)?;
    let files = [tiles::file::TILESET_JSON, "atlas.png", "ais.json"].map(|f| a.dir.join(f));
    let mut inputs: Vec<(&str, &Path)> = tile_paths.iter().map(|p| ("tile", p.as_path())).collect();
    inputs.extend(files.iter().map(|p| ("tile-set file", p.as_path())));
    if let Some(p) = &a.index {
        inputs.push(("--index", p));
    }
    paths::check_files(&[("-o", &a.output)], &inputs, None)?;
    ensure!(
        !paths::place(&a.output).starts_with(paths::resolve(&a.dir)),
        "-o {} lies inside the tile set {}, which `texsyn tiles make` replaces as a whole; write the grid elsewhere",
        a.output.display(),
        a.dir.display()
    );
    Ok(())
}

fn assemble(a: &AssembleArgs) -> Result<()> {
    let file = TileSetFile::read(&a.dir)?;
    let omega = file.omega_set()?;
    let tile_paths = tiles::tile_paths(&a.dir);
    check_output(a, &tile_paths)?;
    let set = tiles::load_tiles(&a.dir, &tile_paths, &file)?;
    let tile = (set[0].width, set[0].height);
    let layout = match &a.index {
        Some(p) => Layout::Index(p),
        None => {
            let (cols, rows) = parse_pair(&a.grid, "--grid")?;
            Layout::Grid {
                cols,
                rows,
                seed: a.seed,
            }
        }
    };
    let index = tiles::layout(layout, set.len(), tile, omega.as_ref(), &Budget::default())?;
    let (cols, rows) = (index[0].len(), index.len());
    imaging::check_output_size(&a.output, cols * tile.0, rows * tile.1)?;
    let img = tiles::assemble(&set, &index)?;
    imaging::save_color(&a.output, &img)?;
    if !a.quiet {
        println!(
            "wrote {}: {cols}x{rows} tiles of {}x{} ({}x{})",
            a.output.display(),
            tile.0,
            tile.1,
            img.width,
            img.height
        );
    }
    Ok(())
}
