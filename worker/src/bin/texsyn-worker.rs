//! `texsyn-worker`: the search engine as a gRPC worker (ARCHITECTURE §4).
//!
//! `texsyn-worker serve --listen ADDR ...` (or just `texsyn-worker --listen ADDR ...`)
//! serves the engine; `texsyn-worker health` asks a running worker. The
//! arguments and the runner live in `texsyn_worker::cli`.

use std::process::ExitCode;

use texsyn_worker::cli;

fn main() -> ExitCode {
    let cli = cli::parse_args();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    match cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("texsyn-worker: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
