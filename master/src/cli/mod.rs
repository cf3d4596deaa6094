//! The `texsyn` command line: each command's flags are parsed into a
//! validated library config, the library runs it, and the command reports
//! (progress through [`progress::Bars`], one line on success). This module
//! holds the command enum and the dispatch; each command has its own file.

use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
pub use cluster::{run_status, ClusterArgs, ClusterSetup, StatusArgs};

mod args;
mod block;
mod block_args;
pub use block_args::{Common, ExtendArgs, FillArgs, MethodArg, MetricArg, StitchArg, SynthArgs};
mod run_args;
pub use run_args::{thread_pool, RunArgs};
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

/// Says what `--lattice auto` found: the log, and stderr unless `quiet`.
fn report_found_lattice(found: Option<crate::lattice::Lattice>, quiet: bool) {
    let line = match found {
        Some(l) => format!(
            "--lattice auto: a grid of {:.2}×{:.2} px (0: that axis free)",
            l.period[0], l.period[1]
        ),
        None => {
            "--lattice auto: no grid found in the sample; running without the lattice phase".into()
        }
    };
    tracing::info!("{line}");
    if !quiet {
        eprintln!("{line}");
    }
}

/// Entry point of the binary after argument parsing.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Fill(a) => block::run_fill(&a),
        Command::Extend(a) => block::run_extend(&a),
        Command::Synth(a) => block::run_synth(&a),
        Command::Cluster(ClusterCommand::Status(a)) => run_status(&a),
        Command::Tiles(t) => tiles::run(t),
        Command::Morph(a) => parallel::run_morph(&a),
        Command::Replay(a) => parallel::run_replay(&a),
        Command::Solid(a) => solid::run(&a),
        Command::Compare(a) => compare::run(&a),
        Command::Match(a) => procedural::run(&a),
    }
}
