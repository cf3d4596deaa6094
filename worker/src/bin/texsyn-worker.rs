//! `texsyn-worker`: the search engine as a gRPC worker.
//!
//! `texsyn-worker serve --listen ADDR ...` (or just `texsyn-worker --listen ADDR ...`)
//! serves the engine; `texsyn-worker health` probes a running worker.
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use texsyn_engine::Kernel;
use texsyn_proto::auth::{read_token, read_token_file, BearerAuth};
use texsyn_proto::wire::listening_line;
use texsyn_worker::service::{self, TlsIdentity, WorkerConfig, DEFAULT_LISTEN};

#[derive(Parser)]
#[command(
    name = "texsyn-worker",
    version,
    about = "texsyn search worker",
    args_conflicts_with_subcommands = true,
    after_help = "Without a subcommand the worker serves: texsyn-worker --listen 127.0.0.1:7878"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    serve: ServeArgs,
}

#[derive(Subcommand)]
enum Command {
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
struct HealthArgs {
    /// Worker address host:port.
    #[arg(long, default_value = DEFAULT_LISTEN)]
    address: String,
    /// File holding the shared token, if the worker requires one.
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 3.0)]
    timeout: f64,
}

#[derive(clap::Args, Debug)]
struct ServeArgs {
    /// Address to listen on (default loopback only; port 0 = any free port).
    #[arg(long, default_value = DEFAULT_LISTEN)]
    listen: SocketAddr,
    /// Search threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// File holding the shared token every call must carry (`authorization: Bearer <token>`).
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// TLS certificate chain (PEM); needs --tls-key.
    #[arg(long, requires = "tls_key")]
    tls_cert: Option<PathBuf>,
    /// TLS private key (PEM); needs --tls-cert.
    #[arg(long, requires = "tls_cert")]
    tls_key: Option<PathBuf>,
    /// Most memory one job may hold, in bytes (suffixes K, M, G allowed; default 3/4 of RAM).
    #[arg(long, value_parser = parse_bytes)]
    max_memory: Option<u64>,
    /// Largest gRPC message, in bytes (suffixes K, M, G allowed).
    #[arg(long, value_parser = parse_bytes, default_value = "64M")]
    max_message: u64,
    /// Free a job's memory this many seconds after its last call (0 = never).
    #[arg(long, default_value_t = 300)]
    idle_timeout: u64,
    /// Kernel: auto, scalar, avx2, avx512.
    #[arg(long, default_value = "auto")]
    kernel: String,
    /// Read the shared token from the first line of stdin (never from the command line).
    #[arg(long, conflicts_with = "token_file")]
    token_stdin: bool,
    /// Shut down when stdin reaches end of file (e.g. when the master's ssh session ends).
    #[arg(long)]
    exit_on_stdin_close: bool,
}

/// Parses `123`, `64K`, `64M`, `8G` (binary units).
fn parse_bytes(s: &str) -> Result<u64, String> {
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
            (Some(c), Some(k)) => Some(TlsIdentity::from_files(c, k)?),
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
            tls,
            max_memory: a.max_memory.unwrap_or(defaults.max_memory),
            max_message,
            idle_timeout: (a.idle_timeout > 0).then(|| Duration::from_secs(a.idle_timeout)),
            kernel: Kernel::from_name(&a.kernel)?,
        };
        config.validate()?;
        Ok(config)
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
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
        None => serve(cli.serve),
        Some(Command::Serve(a)) => serve(a),
        Some(Command::Health(a)) => health(a),
    }
}

fn health(a: HealthArgs) -> anyhow::Result<()> {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    let token = a.token_file.as_deref().map(read_token_file).transpose()?;
    let auth = BearerAuth::new(token.as_deref())?;
    let timeout = Duration::from_secs_f64(a.timeout.clamp(0.1, 600.0));
    let address = if a.address.contains("://") {
        a.address.clone()
    } else {
        format!("http://{}", a.address)
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        let channel = tonic::transport::Endpoint::from_shared(address.clone())
            .with_context(|| format!("'{}' is not a worker address (host:port)", a.address))?
            .connect_timeout(timeout)
            .timeout(timeout)
            .connect()
            .await
            .with_context(|| format!("cannot reach the worker at {}", a.address))?;
        let mut client = HealthClient::with_interceptor(channel, auth);
        let reply = client
            .check(HealthCheckRequest {
                service: String::new(),
            })
            .await
            .with_context(|| format!("health check of {} failed", a.address))?;
        let status = reply.into_inner().status();
        if status != ServingStatus::Serving {
            bail!("worker {} is {:?}", a.address, status);
        }
        println!("{} SERVING", a.address);
        Ok(())
    })
}

/// Reads the token from the first line of stdin (`--token-stdin`).
fn read_token_stdin() -> anyhow::Result<String> {
    let mut line = String::new();
    std::io::stdin()
        .read_line(&mut line)
        .context("cannot read the token from stdin")?;
    read_token(&line).context("--token-stdin: send the shared token on the first line of stdin")
}

/// Completes when stdin reaches end of file (read on a plain thread: stdin
/// reads block).
fn stdin_closed() -> tokio::sync::oneshot::Receiver<()> {
    let (tx, rx) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name("texsyn-stdin".into())
        .spawn(move || {
            use std::io::Read;
            let mut buf = [0u8; 256];
            let mut stdin = std::io::stdin();
            loop {
                match stdin.read(&mut buf) {
                    Ok(0) => break,
                    Ok(_) => continue,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(_) => break,
                }
            }
            let _ = tx.send(());
        })
        .expect("cannot start the stdin thread");
    rx
}

fn serve(args: ServeArgs) -> anyhow::Result<()> {
    let exit_on_stdin_close = args.exit_on_stdin_close;
    let config = WorkerConfig::try_from(args)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("texsyn-io")
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(config.listen)
            .await
            .with_context(|| format!("cannot listen on {}", config.listen))?;
        let local = listener.local_addr()?;
        tracing::info!(%local, "bound");
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", listening_line(local))?;
        out.flush()?;
        drop(out);
        if exit_on_stdin_close {
            let closed = stdin_closed();
            let stop = async move {
                tokio::select! {
                    () = shutdown_signal() => {}
                    _ = closed => tracing::info!("stdin closed; shutting down"),
                }
            };
            service::serve(config, listener, stop).await
        } else {
            service::serve(config, listener, shutdown_signal()).await
        }
    })
}

/// Completes on ctrl-c or SIGTERM.
async fn shutdown_signal() {
    let ctrl_c = async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        () = ctrl_c => {}
        () = term => {}
    }
}
