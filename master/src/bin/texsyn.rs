//! `texsyn`: thin binary over the library (parse, set up tracing and the
//! signal handler, run).
use std::process::ExitCode;

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = texsyn::cli::parse_args();
    if let Err(e) = texsyn::cleanup::install_signal_handlers() {
        eprintln!("texsyn: error: {e:#}");
        return ExitCode::FAILURE;
    }
    match texsyn::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!(
                "texsyn: error: {}",
                texsyn::cli::one_line(&format!("{e:#}"))
            );
            ExitCode::FAILURE
        }
    }
}
