//! The worker process around [`service::serve`]: the async runtime, binding,
//! the `listening on ADDR` line on stdout, and shutdown on ctrl-c, SIGTERM or
//! (with `--exit-on-stdin-close`) the end of stdin, as when the master's ssh
//! session ends (ARCHITECTURE §4, §4.4).

use std::io::Write;

use anyhow::Context;
use texsyn_proto::wire::listening_line;

use crate::service::{self, WorkerConfig, WrongAnswers};

/// Binds `config.listen`, prints the listening line and serves until a
/// shutdown signal (or the end of stdin with `exit_on_stdin_close`).
pub fn serve(config: WorkerConfig, exit_on_stdin_close: bool) -> anyhow::Result<()> {
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
        if config.wrong_answers == WrongAnswers::AfterSigusr1 {
            // Installs tokio's handler before anyone learns the address: a
            // SIGUSR1 sent before the service listens for it must not kill
            // the process (the default action).
            drop(tokio::signal::unix::signal(
                tokio::signal::unix::SignalKind::user_defined1(),
            )?);
        }
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
