//! `texsyn-worker`: the search engine as a gRPC worker, and its benchmark.
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use texsyn_worker::bench::{self, BenchConfig};
use texsyn_worker::Kernel;

#[derive(Parser)]
#[command(
    name = "texsyn-worker",
    version,
    about = "texsyn search worker and kernel benchmark"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Measure the search kernel: GB/s per core for single queries and batches.
    #[command(
        after_help = "Example: texsyn-worker bench --vectors 240000 --dims 192 --queries 64"
    )]
    Bench(BenchArgs),
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Number of reference vectors.
    #[arg(long, default_value_t = 240_000)]
    vectors: usize,
    /// Components per vector (hi part).
    #[arg(long, default_value_t = 192)]
    dims: usize,
    /// Components of the lo (parent) part.
    #[arg(long, default_value_t = 0)]
    lo_dims: usize,
    /// Queries per batch.
    #[arg(long, default_value_t = 64)]
    queries: usize,
    /// Rayon threads (GB/s are reported per thread).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    kernel: String,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Share of query components defined (masks), 0..=1.
    #[arg(long, default_value_t = 1.0)]
    defined: f64,
    /// Minimum seconds per measurement (best repetition reported).
    #[arg(long, default_value_t = 1.0)]
    min_time: f64,
    /// Raw u8 vector file instead of random vectors.
    #[arg(long)]
    vectors_file: Option<std::path::PathBuf>,
    /// Raw u8 query file instead of random queries.
    #[arg(long)]
    queries_file: Option<std::path::PathBuf>,
    /// Write the batched answers ("index distance" per line) to this file.
    #[arg(long)]
    answers_file: Option<std::path::PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("texsyn-worker: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Bench(a) => {
            let cfg = BenchConfig {
                vectors: a.vectors,
                dims: a.dims,
                lo_dims: a.lo_dims,
                queries: a.queries,
                threads: a.threads,
                kernel: Kernel::from_name(&a.kernel)?,
                seed: a.seed,
                defined: a.defined,
                min_time: Duration::from_secs_f64(a.min_time.max(0.0)),
                vectors_file: a.vectors_file,
                queries_file: a.queries_file,
                answers_file: a.answers_file,
            };
            let report = bench::run(&cfg)?;
            if a.json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{report}");
            }
            Ok(())
        }
    }
}
