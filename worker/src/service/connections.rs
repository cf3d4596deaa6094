//! The worker's front door (ARCHITECTURE §4.5): connections are accepted here
//! and handed to the gRPC server only when they behave.
//!
//! - At most `max_connections` are served at once; one more is closed.
//! - A connection that sends no byte within the first-byte timeout is closed
//!   before any TLS or HTTP/2 work is done for it. At most [`MAX_SILENT`]
//!   wait for their first byte; a new one pushes out the oldest, so a flood
//!   of idle sockets cannot keep a master out.
//! - A connection that has made no call past the token check within the
//!   authentication timeout is closed, so idle or unauthenticated sockets are
//!   not kept forever.
//! - TCP keepalive probes find peers that vanished without a FIN.

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit, Semaphore};
use tokio::time::Sleep;
use tokio_stream::wrappers::ReceiverStream;
use tonic::service::Interceptor;
use tonic::transport::server::{Connected, TcpConnectInfo};
use tonic::{Request, Status};

/// Default most open connections.
pub const DEFAULT_MAX_CONNECTIONS: usize = 256;
/// Most connections waiting for their first byte.
pub const MAX_SILENT: usize = 64;
/// How long a new connection has to send its first byte.
pub const FIRST_BYTE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a connection has to make its first authenticated call.
pub const AUTH_TIMEOUT: Duration = Duration::from_secs(30);
/// TCP keepalive: first probe after this idle time, then every interval.
const TCP_KEEPALIVE: Duration = Duration::from_secs(20);
const TCP_KEEPALIVE_INTERVAL: Duration = Duration::from_secs(5);
const TCP_KEEPALIVE_RETRIES: u32 = 3;

/// The limits of [`incoming`].
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    pub max_connections: usize,
    pub first_byte: Duration,
    pub authenticate: Duration,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        Self {
            max_connections: DEFAULT_MAX_CONNECTIONS,
            first_byte: FIRST_BYTE_TIMEOUT,
            authenticate: AUTH_TIMEOUT,
        }
    }
}

/// Connections by peer address, each with its "has made an authenticated
/// call" flag.
#[derive(Default)]
pub(crate) struct Registry {
    open: Mutex<HashMap<SocketAddr, Arc<AtomicBool>>>,
}

impl Registry {
    fn add(&self, peer: SocketAddr) -> Arc<AtomicBool> {
        let flag = Arc::new(AtomicBool::new(false));
        self.lock().insert(peer, flag.clone());
        flag
    }

    fn remove(&self, peer: &SocketAddr) {
        self.lock().remove(peer);
    }

    fn mark(&self, peer: &SocketAddr) {
        if let Some(flag) = self.lock().get(peer) {
            flag.store(true, Ordering::Release);
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<SocketAddr, Arc<AtomicBool>>> {
        self.open.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Marks the caller's connection as authenticated; placed after the token
/// check, so only calls that passed it reach here.
#[derive(Clone)]
pub(crate) struct MarkAuthenticated(pub Arc<Registry>);

impl Interceptor for MarkAuthenticated {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(peer) = request.remote_addr() {
            self.0.mark(&peer);
        }
        Ok(request)
    }
}

/// An accepted connection that holds its slot until it closes.
pub(crate) struct Guarded {
    stream: TcpStream,
    peer: SocketAddr,
    authenticated: Arc<AtomicBool>,
    /// Fires when the connection has not authenticated in time; None once it has.
    deadline: Option<Pin<Box<Sleep>>>,
    registry: Arc<Registry>,
    _slot: OwnedSemaphorePermit,
}

impl Guarded {
    /// The connection's read error once its authentication time is up.
    fn expired(&mut self, cx: &mut Context<'_>) -> Option<io::Error> {
        let deadline = self.deadline.as_mut()?;
        if self.authenticated.load(Ordering::Acquire) {
            self.deadline = None;
            return None;
        }
        if deadline.as_mut().poll(cx).is_ready() {
            tracing::debug!(peer = %self.peer, "no authenticated call in time; closing the connection");
            return Some(io::Error::new(
                io::ErrorKind::TimedOut,
                "no authenticated call in time",
            ));
        }
        None
    }
}

impl Drop for Guarded {
    fn drop(&mut self) {
        self.registry.remove(&self.peer);
    }
}

impl AsyncRead for Guarded {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if let Some(e) = self.expired(cx) {
            return Poll::Ready(Err(e));
        }
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for Guarded {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

impl Connected for Guarded {
    type ConnectInfo = TcpConnectInfo;

    fn connect_info(&self) -> TcpConnectInfo {
        self.stream.connect_info()
    }
}

/// The connections waiting for their first byte, oldest first, each with the
/// switch that closes it.
#[derive(Default)]
struct Silent {
    waiting: Mutex<Waiting>,
}

/// The next id, and the waiting connections' ids and close switches.
type Waiting = (u64, VecDeque<(u64, oneshot::Sender<()>)>);

impl Silent {
    /// Registers a new connection (pushing out the oldest when
    /// [`MAX_SILENT`] wait already): its id and its close signal.
    fn enter(&self) -> (u64, oneshot::Receiver<()>) {
        let (close, closed) = oneshot::channel();
        let mut w = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
        let id = w.0;
        w.0 += 1;
        while w.1.len() >= MAX_SILENT {
            if let Some((_, oldest)) = w.1.pop_front() {
                let _ = oldest.send(());
            }
        }
        w.1.push_back((id, close));
        (id, closed)
    }

    fn leave(&self, id: u64) {
        let mut w = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(k) = w.1.iter().position(|(i, _)| *i == id) {
            w.1.remove(k);
        }
    }
}

/// Sets TCP_NODELAY and keepalive probes on an accepted socket.
fn tune(stream: &TcpStream) -> io::Result<()> {
    stream.set_nodelay(true)?;
    let keepalive = socket2::TcpKeepalive::new()
        .with_time(TCP_KEEPALIVE)
        .with_interval(TCP_KEEPALIVE_INTERVAL)
        .with_retries(TCP_KEEPALIVE_RETRIES);
    socket2::SockRef::from(stream).set_tcp_keepalive(&keepalive)
}

/// Accepts on `listener` under `limits`; the stream of connections that sent
/// their first byte in time, for `serve_with_incoming`. The accept loop ends
/// when the stream is dropped.
pub(crate) fn incoming(
    listener: TcpListener,
    limits: ConnectionLimits,
    registry: Arc<Registry>,
) -> ReceiverStream<io::Result<Guarded>> {
    let (tx, rx) = mpsc::channel(64);
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let silent = Arc::new(Silent::default());
    tokio::spawn(async move {
        loop {
            let accepted = tokio::select! {
                a = listener.accept() => a,
                () = tx.closed() => break,
            };
            let (stream, peer) = match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: back off, keep serving.
                    tracing::warn!(error = %e, "accept failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            let (id, evicted) = silent.enter();
            if let Err(e) = tune(&stream) {
                tracing::debug!(%peer, error = %e, "cannot set socket options");
            }
            let (tx, registry, silent, slots) =
                (tx.clone(), registry.clone(), silent.clone(), slots.clone());
            tokio::spawn(async move {
                // `peek` waits for a byte really there (readiness alone can be
                // reported for a socket that has sent nothing).
                let mut byte = [0u8; 1];
                let first = tokio::select! {
                    r = tokio::time::timeout(limits.first_byte, stream.peek(&mut byte)) => Some(r),
                    _ = evicted => None,
                };
                silent.leave(id);
                match first {
                    Some(Ok(Ok(0))) => {
                        tracing::debug!(%peer, "connection closed before its first byte");
                        return;
                    }
                    Some(Ok(Ok(_))) => {}
                    Some(Ok(Err(e))) => {
                        tracing::debug!(%peer, error = %e, "connection failed before its first byte");
                        return;
                    }
                    Some(Err(_)) => {
                        tracing::debug!(%peer, "no first byte in {:?}; closing the connection", limits.first_byte);
                        return;
                    }
                    None => {
                        tracing::debug!(%peer, "pushed out by newer connections before its first byte");
                        return;
                    }
                }
                // Only connections that speak hold a slot, so silent ones
                // never keep a client out.
                let Ok(slot) = slots.try_acquire_owned() else {
                    tracing::warn!(%peer, max = limits.max_connections, "connection limit reached; closing the new connection");
                    return;
                };
                let authenticated = registry.add(peer);
                let conn = Guarded {
                    stream,
                    peer,
                    authenticated,
                    deadline: Some(Box::pin(tokio::time::sleep(limits.authenticate))),
                    registry,
                    _slot: slot,
                };
                let _ = tx.send(Ok(conn)).await;
            });
        }
    });
    ReceiverStream::new(rx)
}
