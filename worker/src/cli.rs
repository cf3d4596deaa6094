//! The `texsyn-worker` command line: its clap argument types, the conversion of
//! the serve flags into a [`WorkerConfig`] and the command runner
//! (ARCHITECTURE §4, §4.4 for the token and TLS flags).
//!
//! `texsyn-worker serve --listen ADDR ...` (or just `texsyn-worker --listen ADDR ...`)
//! serves the engine; `texsyn-worker health` asks a running worker.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use texsyn_engine::{Kernel, Storage};
use texsyn_proto::auth::{read_token, read_token_file};
use texsyn_proto::tls::TlsArgs;

use crate::service::{TlsIdentity, WorkerConfig, WrongAnswers, DEFAULT_LISTEN};

/// `texsyn-worker`'s arguments: a subcommand, or the serve flags directly.
#[derive(Parser)]
#[command(
    name = "texsyn-worker",
    version,
    about = "texsyn search worker",
    args_conflicts_with_subcommands = true,
    after_help = "Without a subcommand the worker serves: texsyn-worker --listen 127.0.0.1:7878"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    #[command(flatten)]
    pub serve: ServeArgs,
}

#[derive(Subcommand)]
pub enum Command {
    /// Serve the search engine over gRPC to a texsyn master.
    #[command(
        after_help = "Prints `listening on ADDR` on stdout once bound (use port 0 for a free port).\n\
                      Example: texsyn-worker serve --listen 0.0.0.0:7878 --token-file /etc/texsyn/token"
    )]
    Serve(ServeArgs),
    /// Ask a running worker's health service; exit 0 when it is SERVING (for
    /// container and Kubernetes probes).
    #[command(
        after_help = "Example: texsyn-worker health --address 127.0.0.1:7878 --token-file /etc/texsyn/token"
    )]
    Health(HealthArgs),
}

#[derive(clap::Args)]
pub struct HealthArgs {
    /// Worker address: host:port, https://host:port (TLS) or http://host:port.
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub address: String,
    /// File holding the shared token, if the worker requires one.
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Seconds to wait for the answer (0.1 to 600).
    #[arg(long, default_value_t = 3.0, value_name = "SECONDS",
          value_parser = |s: &str| parse_seconds(s, HEALTH_TIMEOUT.0, HEALTH_TIMEOUT.1))]
    pub timeout: f64,
    #[command(flatten)]
    pub tls: TlsArgs,
}

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Address to listen on (default loopback only; port 0 = any free port).
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
    /// Search threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// File holding the shared token every call must carry (`authorization: Bearer <token>`).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// TLS certificate chain (PEM); needs --tls-key.
    #[arg(long, requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// TLS private key (PEM); needs --tls-cert.
    #[arg(long, requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Mutual TLS: require every client to present a certificate signed by
    /// this CA (PEM); needs --tls-cert and --tls-key.
    #[arg(long, value_name = "FILE")]
    pub tls_client_ca: Option<PathBuf>,
    /// Most memory the worker may hold for all jobs and calls together, in
    /// bytes (suffixes K, M, G allowed; default 3/4 of the RAM or of the
    /// control group's memory limit, whichever is smaller).
    #[arg(long, value_parser = parse_bytes)]
    pub max_memory: Option<u64>,
    /// Largest gRPC message, in bytes (suffixes K, M, G allowed).
    #[arg(long, value_parser = parse_bytes, default_value = "64M")]
    pub max_message: u64,
    /// Free a job's memory this many seconds after its last call (0 = never; at most 30 days).
    #[arg(long, default_value_t = 300, value_name = "SECONDS",
          value_parser = clap::value_parser!(u64).range(0..=MAX_IDLE_TIMEOUT))]
    pub idle_timeout: u64,
    /// Most connections open at once; more are closed at accept.
    #[arg(long, default_value_t = crate::service::DEFAULT_MAX_CONNECTIONS)]
    pub max_connections: usize,
    /// Kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    pub kernel: String,
    /// Microseconds the search threads spin for more work after each search
    /// before they sleep (0: sleep at once); answers are the same either way.
    #[arg(long, value_name = "US", default_value_t = texsyn_engine::search::DEFAULT_SPIN.as_micros() as u64,
          value_parser = clap::value_parser!(u64).range(0..=1_000_000))]
    pub spin_us: u64,
    /// How a range's vectors are held: dense (built once, fastest), planes
    /// (gathered from the sample as they are scanned: about one byte per
    /// sample pixel) or auto (dense while they fit in 1 GiB and half of --max-memory).
    #[arg(long, default_value = "auto")]
    pub vector_store: String,
    /// Serve a non-loopback --listen address without a token. Anyone who can
    /// reach the port can then use the worker: only for networks you trust.
    #[arg(long)]
    pub insecure_no_auth: bool,
    /// Fault injection for tests: answer every search with a wrong reference
    /// at distance 0 (the master must detect it and drop this worker).
    #[arg(long, hide = true)]
    pub fault_wrong_answers: bool,
    /// Fault injection for the fault campaign: answer truthfully until the
    /// process receives SIGUSR1, wrongly from then on.
    #[arg(long, hide = true, conflicts_with = "fault_wrong_answers")]
    pub fault_wrong_answers_on_sigusr1: bool,
    /// Fault injection for tests: while searching a linked batch, report
    /// distance 0 for every query; answer truthfully.
    #[arg(long, hide = true)]
    pub fault_low_reports: bool,
    /// Read the shared token from the first line of stdin (never from the command line).
    #[arg(long, conflicts_with = "token_file")]
    pub token_stdin: bool,
    /// Shut down when stdin reaches end of file (e.g. when the master's ssh session ends).
    #[arg(long)]
    pub exit_on_stdin_close: bool,
}

/// Range of `health --timeout`, in seconds.
const HEALTH_TIMEOUT: (f64, f64) = (0.1, 600.0);
/// Largest `--idle-timeout`, in seconds (30 days).
const MAX_IDLE_TIMEOUT: u64 = 30 * 24 * 3600;

pub use texsyn_proto::cli::parse_seconds;

/// Parses the command line. A usage error (unknown flag, bad value) is
/// printed as one line `texsyn-worker: error: ...` and exits with code 1;
/// help and version go out as clap prints them.
pub fn parse_args() -> Cli {
    texsyn_proto::cli::parse_or_exit("texsyn-worker")
}

/// Parses `123`, `64K`, `64M`, `8G` (binary units).
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (num, shift) = match t.char_indices().last() {
        Some((i, 'k' | 'K')) => (&t[..i], 10),
        Some((i, 'm' | 'M')) => (&t[..i], 20),
        Some((i, 'g' | 'G')) => (&t[..i], 30),
        _ => (t, 0),
    };
    let n: u64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a byte count (e.g. 1048576, 64M, 8G)"))?;
    n.checked_mul(1u64 << shift)
        .ok_or_else(|| format!("'{s}' is too large"))
}

/// The serve flags as a checked configuration; reads the token (file or the
/// first line of stdin) and the TLS identity.
impl TryFrom<ServeArgs> for WorkerConfig {
    type Error = anyhow::Error;

    fn try_from(a: ServeArgs) -> anyhow::Result<Self> {
        let defaults = WorkerConfig::default();
        let token = if a.token_stdin {
            Some(read_token_stdin()?)
        } else {
            a.token_file.as_deref().map(read_token_file).transpose()?
        };
        let tls = match (&a.tls_cert, &a.tls_key) {
            (Some(c), Some(k)) => {
                let id = TlsIdentity::from_files(c, k)?;
                Some(match &a.tls_client_ca {
                    Some(ca) => id.with_client_ca(ca)?,
                    None => id,
                })
            }
            (None, None) if a.tls_client_ca.is_some() => {
                bail!("--tls-client-ca needs --tls-cert and --tls-key: mutual TLS is TLS first")
            }
            (None, None) => None,
            (Some(_), None) => bail!("--tls-cert was given without --tls-key; TLS needs both"),
            (None, Some(_)) => bail!("--tls-key was given without --tls-cert; TLS needs both"),
        };
        let max_message = usize::try_from(a.max_message)
            .with_context(|| format!("--max-message {} is too large", a.max_message))?;
        let config = WorkerConfig {
            listen: a.listen,
            threads: a.threads.unwrap_or(defaults.threads),
            token,
            insecure_no_auth: a.insecure_no_auth,
            tls,
            max_memory: a.max_memory.unwrap_or(defaults.max_memory),
            max_message,
            idle_timeout: (a.idle_timeout > 0).then(|| Duration::from_secs(a.idle_timeout)),
            kernel: Kernel::from_name(&a.kernel)?,
            spin: Duration::from_micros(a.spin_us),
            storage: Storage::from_name(&a.vector_store)?,
            wrong_answers: if a.fault_wrong_answers {
                WrongAnswers::Always
            } else if a.fault_wrong_answers_on_sigusr1 {
                WrongAnswers::AfterSigusr1
            } else {
                WrongAnswers::Never
            },
            low_reports: a.fault_low_reports,
            connections: crate::service::ConnectionLimits {
                max_connections: a.max_connections,
                ..Default::default()
            },
        };
        config.validate()?;
        Ok(config)
    }
}

/// Reads the token from the first line of stdin (`--token-stdin`).
fn read_token_stdin() -> anyhow::Result<String> {
    let mut line = String::new();
    std::io::stdin()
        .read_line(&mut line)
        .context("cannot read the token from stdin")?;
    read_token(&line).context("--token-stdin: send the shared token on the first line of stdin")
}

/// Runs the command: serve (the default) or a health check.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        None => serve(cli.serve),
        Some(Command::Serve(a)) => serve(a),
        Some(Command::Health(a)) => crate::health::check(
            &a.address,
            a.token_file.as_deref(),
            &a.tls.load()?,
            texsyn_proto::cli::check_seconds(
                a.timeout,
                &a.timeout.to_string(),
                HEALTH_TIMEOUT.0,
                HEALTH_TIMEOUT.1,
            )
            .map(Duration::from_secs_f64)
            .map_err(|e| anyhow::anyhow!("--timeout: {e}"))?,
        ),
    }
}

fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let exit_on_stdin_close = args.exit_on_stdin_close;
    let config = WorkerConfig::try_from(args)?;
    crate::process::serve(config, exit_on_stdin_close)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_parse() {
        assert_eq!(parse_bytes("123"), Ok(123));
        assert_eq!(parse_bytes("64K"), Ok(64 << 10));
        assert_eq!(parse_bytes("64m"), Ok(64 << 20));
        assert_eq!(parse_bytes(" 8G "), Ok(8 << 30));
        assert!(parse_bytes("x").is_err());
        assert!(parse_bytes("99999999999G").is_err());
    }

    #[test]
    fn durations_are_validated() {
        assert_eq!(parse_seconds("2.5", 0.1, 600.0), Ok(2.5));
        for bad in ["nan", "inf", "-1", "1e300", "0", "x", ""] {
            assert!(parse_seconds(bad, 0.1, 600.0).is_err(), "{bad}");
        }
        for args in [
            &["texsyn-worker", "health", "--timeout", "nan"][..],
            &["texsyn-worker", "health", "--timeout", "inf"],
            &["texsyn-worker", "health", "--timeout", "-3"],
            &["texsyn-worker", "serve", "--idle-timeout", "99999999999"],
            &["texsyn-worker", "serve", "--idle-timeout", "-1"],
        ] {
            assert!(Cli::try_parse_from(args).is_err(), "{args:?}");
        }
        let cli = Cli::try_parse_from(["texsyn-worker", "health", "--timeout", "0.5"]).unwrap();
        assert!(matches!(cli.command, Some(Command::Health(h)) if h.timeout == 0.5));
    }

    #[test]
    fn no_subcommand_serves() {
        let cli = Cli::try_parse_from(["texsyn-worker", "--listen", "127.0.0.1:0"]).unwrap();
        assert!(cli.command.is_none());
        assert_eq!(cli.serve.listen, "127.0.0.1:0".parse().unwrap());
        assert!(Cli::try_parse_from(["texsyn-worker", "bench"]).is_err());
        assert!(Cli::try_parse_from([
            "texsyn-worker",
            "serve",
            "--token-stdin",
            "--token-file",
            "t"
        ])
        .is_err());
    }
}
