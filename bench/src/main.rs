//! `texsyn-bench`: texsyn's benchmarks (ARCHITECTURE §6), one subcommand each:
//! the paper's configurations end to end (Stahlhut Table 1, §10.2), LBG
//! against exhaustive search (Stahlhut §8), the cluster on loopback, the
//! search kernel and the synthesis on coordinates.
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cases;
mod cluster;
mod faults;
mod kernel;
mod large;
mod lbg;
mod morph;
mod paper;
mod procedural;
mod quality;
mod scale;
mod sheet;
mod solid;

const EXAMPLES: &str = "Examples:
  texsyn-bench paper
  texsyn-bench paper --case a --reps 5 --out /tmp/bench
  texsyn-bench lbg --lbg-probes 1,2,4
  texsyn-bench cluster --batches 60
  texsyn-bench kernel --vectors 240000 --dims 192 --queries 64
  texsyn-bench large ../shared/textures/mossy_rock_color_1024.png --size 1024x1024 --unpruned
  texsyn-bench upscale ../shared/textures/mossy_rock_color_1024.png -o /tmp/rock_8192.png --factor 8
  texsyn-bench morph --reps 3 --out /tmp/morph
  texsyn-bench solid --sizes 64,128,256 --neighbourhoods half,7
  texsyn-bench faults --runs 50 --seed 1 --json /tmp/faults.json
  texsyn-bench quality --max-side 256 -o /tmp/quality
  texsyn-bench scale ../shared/textures/mossy_rock_color_1024.png --threads 2,4,8,16 --cluster-size 2048x2048 --workers 4x4,8x2
  texsyn-bench match --draws 10 --photos ../shared/textures/brick_color_96.png --out /tmp/match
  /usr/bin/time -v texsyn synth /tmp/rock_8192.png -o /tmp/out.png --size 512x512 [--local-workers 2]

Textures default to the repository's assets/textures (give --textures DIR elsewhere).";

#[derive(Parser)]
#[command(
    name = "texsyn-bench",
    version,
    about = "texsyn benchmarks: the paper's configurations, LBG, the loopback cluster, the search kernel",
    after_help = EXAMPLES
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The paper's configurations end to end: (a) 192×192 from 64×64 (9×9, 3×3,
    /// 3 levels) and (b) 1000×1000 from 500×500 (11×11, 5×5, 4 levels).
    #[command(after_help = "Example: texsyn-bench paper --case a --reps 5")]
    Paper(paper::PaperArgs),
    /// LBG against exhaustive search per level of (a) and (b) for P = 1, 2, 4,
    /// then (b) end to end with LBG on the finest level.
    #[command(after_help = "Example: texsyn-bench lbg --lbg-probes 1,2,4 --reps 3")]
    Lbg(lbg::LbgArgs),
    /// 2 local workers (1 thread each) against the local engine (2 threads) on
    /// the finest level of (b): latency, throughput ratio, memory.
    #[command(after_help = "Example: texsyn-bench cluster --batch 64 --batches 60 --reps 5")]
    Cluster(cluster::ClusterArgs),
    /// The search kernel: GB/s per core for single queries and batches.
    #[command(
        after_help = "Example: texsyn-bench kernel --vectors 240000 --dims 192 --queries 64"
    )]
    Kernel(kernel::KernelArgs),
    /// A large sample end to end: pruned exact search against the unpruned
    /// scan (same output) and Embark's texture-synthesis when installed.
    #[command(
        after_help = "Example: texsyn-bench large ../shared/textures/mossy_rock_color_1024.png --unpruned"
    )]
    Large(large::LargeArgs),
    /// Makes a large sample from a photo by Lanczos upscaling (grey by
    /// default), e.g. the 8192² sample of the large-sample case (3).
    #[command(
        after_help = "Example: texsyn-bench upscale ../shared/textures/mossy_rock_color_1024.png -o /tmp/rock_8192.png --factor 8"
    )]
    Upscale(large::UpscaleArgs),
    /// The synthesis on coordinates: a 512² morph of two exemplars per
    /// neighbourhood, then `--method parallel` against the block method.
    #[command(after_help = "Example: texsyn-bench morph --reps 3 --out /tmp/morph")]
    Morph(morph::MorphArgs),
    /// Solid textures: time and peak memory per size and neighbourhood (each
    /// run its own process), then the faces' scores against the exemplar.
    #[command(
        after_help = "Example: texsyn-bench solid --sizes 64,128,256 --neighbourhoods half,7"
    )]
    Solid(solid::SolidArgs),
    /// The seeded fault campaign: cluster runs with random kills, stops,
    /// partitions, restarts, slowed and lying workers; every output must be
    /// bit-identical, nothing left behind.
    #[command(
        after_help = "Example (as root, for partitions): texsyn-bench faults --runs 50 --seed 1"
    )]
    Faults(faults::FaultArgs),
    /// Procedural matching (Bourque–Dudek): recovery of synthetic targets
    /// per shader, match time per target, matches of photos.
    #[command(
        after_help = "Example: texsyn-bench match --draws 10 --photos ../shared/textures/pink_marble_color_128.png --out /tmp/match"
    )]
    Match(procedural::MatchArgs),
    /// Every method over a list of textures at 2× the sample's side: a JSON
    /// table of `texsyn compare`'s figures with time and peak memory, and a
    /// contact sheet.
    #[command(
        after_help = "Example: texsyn-bench quality assets/textures --methods block,somol -o /tmp/quality"
    )]
    Quality(quality::QualityArgs),
    /// Exact synthesis over thread counts and local workers: time, speed-up,
    /// efficiency, identical output, and where the finest level's time went.
    #[command(
        after_help = "Example: texsyn-bench scale ../shared/textures/mossy_rock_color_1024.png --threads 1,2 --size 768x768"
    )]
    Scale(scale::ScaleArgs),
    /// Runs a command and writes its wall time and peak memory (the helper of
    /// `quality` and `solid`).
    #[command(hide = true)]
    MeasureChild(cases::MeasureChildArgs),
    /// Spins on one core (the neighbour of a slowed worker in `faults`).
    #[command(hide = true)]
    Hog(faults::HogArgs),
}

/// A level's pruning figures in a few words: pairs abandoned and component
/// work skipped.
pub(crate) fn prune_text(p: Option<texsyn_engine::PruneStats>) -> String {
    match p {
        Some(p) if p.pairs > 0 => format!(
            "{:.1}% pairs, {:.1}% work",
            100.0 * p.pairs_skipped(),
            100.0 * p.components_skipped()
        ),
        _ => "-".into(),
    }
}

fn main() -> ExitCode {
    // A report piped into `head` meets a closed pipe: end quietly, as Unix
    // tools do, instead of panicking in `println!`.
    // SAFETY: restoring a signal's default disposition at start-up, before
    // any thread exists.
    #[cfg(unix)]
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let result = match Cli::parse().command {
        Command::Paper(a) => paper::run(&a),
        Command::Lbg(a) => lbg::run(&a),
        Command::Cluster(a) => cluster::run(&a),
        Command::Kernel(a) => kernel::run(a),
        Command::Large(a) => large::run(&a),
        Command::Upscale(a) => large::upscale(&a),
        Command::Morph(a) => morph::run(&a),
        Command::Solid(a) => solid::run(&a),
        Command::Faults(a) => faults::run(&a),
        Command::Hog(a) => faults::hog(&a),
        Command::Match(a) => procedural::run(&a),
        Command::Quality(a) => quality::run(&a),
        Command::MeasureChild(a) => cases::measure_child(&a),
        Command::Scale(a) => scale::run(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("texsyn-bench: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    #[test]
    fn arguments_are_consistent() {
        super::Cli::command().debug_assert();
    }

    #[test]
    fn default_textures_are_the_repository_assets() {
        let t = crate::cases::Textures { textures: None };
        let dir = t.dir().expect("assets/textures");
        assert!(dir.join("gravel_gray_500.png").is_file());
        assert!(dir.join("brick_gray_64.png").is_file());
    }
}
