//! The gRPC worker (ARCHITECTURE §4, Stahlhut §8): serves the search [`Engine`] of
//! this crate to a master over the `texsyn.v1.Worker` protocol.
//!
//! A worker holds, per job, the level images the master sent and the reference
//! vectors of the index range it was assigned; the master keeps the truth (the
//! canvas and the partition table), so everything here is a cache it can rebuild.
//! Searches run on a dedicated rayon pool, never on the gRPC I/O threads.
//!
//! Security: the listener binds where it is told (default loopback), a shared
//! token is checked on every call (health checks included), TLS is optional,
//! message sizes and memory are capped, and every request is validated before
//! anything is allocated for it: a malformed request gets a gRPC status, never a
//! panic.
//!
//! [`Engine`]: texsyn_engine::Engine

mod budget;
mod config;
mod connections;
mod rpc;
mod state;

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use texsyn_proto::v1::worker_server::WorkerServer;
use tokio::net::TcpListener;
use tonic::codegen::http;
use tonic::service::InterceptorLayer;
use tonic::transport::{Certificate, Identity, Server, ServerTlsConfig};

pub use budget::default_max_memory;
pub use config::{
    TlsIdentity, WorkerConfig, WrongAnswers, DEFAULT_IDLE_TIMEOUT, DEFAULT_LISTEN,
    DEFAULT_MAX_MESSAGE,
};
pub use connections::{
    ConnectionLimits, AUTH_TIMEOUT, DEFAULT_MAX_CONNECTIONS, FIRST_BYTE_TIMEOUT,
};
pub use rpc::WorkerService;

use state::Shared;
use texsyn_proto::auth::TokenCheck;

/// How long open connections (a master's long-lived search streams) get to
/// finish after the shutdown signal before the server stops anyway.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);
/// Most concurrent HTTP/2 streams (calls) on one connection. High enough
/// that a client never queues streams in practice: HTTP/2 clients that queue
/// beyond the server's limit can stall (hyperium/hyper#3559), and a stream
/// costs little here, since every call's memory is reserved from the budget
/// and the connection's flow-control window bounds what waits unread.
pub const MAX_STREAMS_PER_CONNECTION: u32 = 1024;
/// HTTP/2 pings on idle connections, and how long an answer may take before
/// the connection is dropped as dead.
const HTTP2_KEEPALIVE: Duration = Duration::from_secs(10);
const HTTP2_KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest TLS handshake.
const TLS_HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// tonic reports a message over the size limit as OUT_OF_RANGE; gRPC says
/// RESOURCE_EXHAUSTED. No handler here returns OUT_OF_RANGE, so the code is
/// translated for every status that travels in the response headers (unary
/// calls); search streams translate theirs in the stream.
fn size_status_in_headers<B>(mut response: http::Response<B>) -> http::Response<B> {
    let out_of_range = (tonic::Code::OutOfRange as i32).to_string();
    if response
        .headers()
        .get("grpc-status")
        .is_some_and(|v| v.as_bytes() == out_of_range.as_bytes())
    {
        let exhausted = (tonic::Code::ResourceExhausted as i32).to_string();
        if let Ok(v) = http::HeaderValue::from_str(&exhausted) {
            response.headers_mut().insert("grpc-status", v);
        }
    }
    response
}

/// Turns tonic's OUT_OF_RANGE for an oversized message into RESOURCE_EXHAUSTED.
pub(crate) fn size_status(status: tonic::Status) -> tonic::Status {
    if status.code() == tonic::Code::OutOfRange {
        tonic::Status::resource_exhausted(status.message().to_string())
    } else {
        status
    }
}

/// Serves the worker on an already bound `listener` until `shutdown` completes.
///
/// Bind first (port 0 is fine), read `listener.local_addr()`, then call this; the
/// binary prints [`listening_line`] in between. The health service
/// (`grpc.health.v1`) reports `texsyn.v1.Worker` as SERVING while this runs.
/// On shutdown, running search streams end with UNAVAILABLE and open
/// connections get [`SHUTDOWN_GRACE`] to close.
pub async fn serve(
    config: WorkerConfig,
    listener: TcpListener,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    config.validate()?;
    let local = listener
        .local_addr()
        .context("the listener has no local address")?;
    config.check_exposure(local)?;
    if config.token.is_none() && !local.ip().is_loopback() {
        tracing::warn!(
            %local,
            "--insecure-no-auth: listening on a non-loopback address without a token; anyone who can reach it may use this worker"
        );
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads)
        .thread_name(|i| format!("texsyn-search-{i}"))
        .build()
        .context("cannot start the search thread pool")?;
    let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
    let shared = Arc::new(Shared::new(&config, pool, stop_rx));
    let reaper = config
        .idle_timeout
        .map(|idle| tokio::spawn(state::reap_idle_jobs(shared.clone(), idle)));

    let liar = (config.wrong_answers == WrongAnswers::AfterSigusr1)
        .then(|| lie_after_sigusr1(shared.clone()))
        .transpose()?;
    let service = WorkerService::new(shared.clone());
    let worker = WorkerServer::new(service)
        .max_decoding_message_size(config.max_message)
        .max_encoding_message_size(config.max_message);
    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<WorkerServer<WorkerService>>().await;

    let mut builder = Server::builder()
        .max_concurrent_streams(MAX_STREAMS_PER_CONNECTION)
        .http2_keepalive_interval(Some(HTTP2_KEEPALIVE))
        .http2_keepalive_timeout(Some(HTTP2_KEEPALIVE_TIMEOUT));
    if let Some(tls) = &config.tls {
        let identity = Identity::from_pem(&tls.cert_pem, &tls.key_pem);
        let mut tls_config = ServerTlsConfig::new()
            .identity(identity)
            .timeout(TLS_HANDSHAKE_TIMEOUT);
        if let Some(ca) = &tls.client_ca_pem {
            tls_config = tls_config.client_ca_root(Certificate::from_pem(ca));
        }
        builder = builder
            .tls_config(tls_config)
            .context("invalid TLS certificate, key or client CA")?;
    }
    let registry = Arc::new(connections::Registry::default());
    let layers = tower::ServiceBuilder::new()
        .map_response(size_status_in_headers)
        .layer(InterceptorLayer::new(TokenCheck::new(
            config.token.as_deref(),
        )))
        .layer(InterceptorLayer::new(connections::MarkAuthenticated(
            registry.clone(),
        )));
    let router = builder
        .layer(layers)
        .add_service(health_service)
        .add_service(worker);

    tracing::info!(
        %local,
        threads = config.threads,
        kernel = shared.engine.kernel().name(),
        tls = config.tls.is_some(),
        mutual_tls = config.tls.as_ref().is_some_and(|t| t.client_ca_pem.is_some()),
        token = config.token.is_some(),
        max_message = config.max_message,
        max_memory = config.max_memory,
        max_connections = config.connections.max_connections,
        "texsyn worker listening"
    );

    let incoming = connections::incoming(listener, config.connections, registry);
    let (signal_tx, signal_rx) = tokio::sync::oneshot::channel::<()>();
    let server = router.serve_with_incoming_shutdown(incoming, async {
        let _ = signal_rx.await;
    });
    tokio::pin!(server);
    tokio::pin!(shutdown);
    let result = tokio::select! {
        r = &mut server => r,
        () = &mut shutdown => {
            tracing::info!("shutting down");
            health.set_not_serving::<WorkerServer<WorkerService>>().await;
            let _ = stop_tx.send(true);
            let _ = signal_tx.send(());
            match tokio::time::timeout(SHUTDOWN_GRACE, &mut server).await {
                Ok(r) => r,
                Err(_) => {
                    tracing::warn!("connections still open after {:?}; stopping anyway", SHUTDOWN_GRACE);
                    Ok(())
                }
            }
        }
    };
    for task in reaper.into_iter().chain(liar) {
        task.abort();
    }
    shared.clear();
    result.context("gRPC server failed")
}

/// Fault injection: from the first SIGUSR1 on, searches are answered wrongly.
fn lie_after_sigusr1(shared: Arc<Shared>) -> anyhow::Result<tokio::task::JoinHandle<()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut usr1 = signal(SignalKind::user_defined1()).context("cannot catch SIGUSR1")?;
    Ok(tokio::spawn(async move {
        if usr1.recv().await.is_some() {
            tracing::warn!(
                "SIGUSR1: fault injection on, searches are answered wrongly from now on"
            );
            shared
                .wrong_answers
                .store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }))
}
