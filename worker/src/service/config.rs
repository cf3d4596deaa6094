//! The worker's validated configuration.

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context};

use texsyn_engine::{Kernel, Storage};

use super::budget::default_max_memory;
use super::connections::ConnectionLimits;

/// Default listen address: loopback only, so a worker is never exposed by accident.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
/// Default cap on decoded and encoded gRPC messages.
pub const DEFAULT_MAX_MESSAGE: usize = 64 << 20;
/// Default time after its last call that a job's memory is freed.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(300);

const MIN_MAX_MESSAGE: usize = 4 << 10;
/// h2 and prost lengths are 32-bit.
const MAX_MAX_MESSAGE: usize = (2 << 30) - 1;
const MIN_MAX_MEMORY: u64 = 1 << 20;
const MAX_THREADS: usize = 4096;
const MAX_CONNECTIONS: usize = 1 << 16;

/// A PEM certificate chain and private key for TLS, and the CA of the client
/// certificates to require (mutual TLS).
#[derive(Clone)]
pub struct TlsIdentity {
    pub cert_pem: Vec<u8>,
    pub key_pem: Vec<u8>,
    /// PEM CA: when set, every client must present a certificate it signed.
    pub client_ca_pem: Option<Vec<u8>>,
}

impl TlsIdentity {
    /// Reads the PEM files.
    pub fn from_files(cert: &Path, key: &Path) -> anyhow::Result<Self> {
        let cert_pem = std::fs::read(cert)
            .with_context(|| format!("cannot read the TLS certificate {}", cert.display()))?;
        let key_pem = std::fs::read(key)
            .with_context(|| format!("cannot read the TLS key {}", key.display()))?;
        Ok(Self {
            cert_pem,
            key_pem,
            client_ca_pem: None,
        })
    }

    /// Requires client certificates signed by the CA in `ca` (`--tls-client-ca`).
    pub fn with_client_ca(self, ca: &Path) -> anyhow::Result<Self> {
        Ok(Self {
            client_ca_pem: Some(texsyn_proto::tls::read_cert_pem(ca, "--tls-client-ca")?),
            ..self
        })
    }
}

impl std::fmt::Debug for TlsIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TlsIdentity")
            .field("cert_pem", &format_args!("{} bytes", self.cert_pem.len()))
            .field("key_pem", &"<redacted>")
            .field("client_ca", &self.client_ca_pem.is_some())
            .finish()
    }
}

/// Fault injection: when a worker answers searches with made-up references
/// at distance 0, which win any merge that does not check them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WrongAnswers {
    Never,
    /// Every search (`--fault-wrong-answers`).
    Always,
    /// Every search after the process receives SIGUSR1
    /// (`--fault-wrong-answers-on-sigusr1`): a lie at a time of the test's choosing.
    AfterSigusr1,
}

/// Everything `texsyn-worker serve` is configured with. Build it with
/// [`WorkerConfig::default`] and set fields; [`crate::service::serve`] calls
/// [`WorkerConfig::validate`].
#[derive(Clone)]
pub struct WorkerConfig {
    /// Where the binary binds (the library is handed a bound listener).
    pub listen: SocketAddr,
    /// Threads of the search pool.
    pub threads: usize,
    /// Shared secret every call must carry as `authorization: Bearer <token>`.
    pub token: Option<String>,
    /// Serve a non-loopback address without a token (`--insecure-no-auth`):
    /// anyone who can reach the port may use the worker.
    pub insecure_no_auth: bool,
    pub tls: Option<TlsIdentity>,
    /// Most bytes the worker may hold for all jobs and calls together
    /// (level images, positions, vectors, keys and per-call buffers).
    pub max_memory: u64,
    /// Largest gRPC message decoded or encoded, in bytes.
    pub max_message: usize,
    /// Free a job this long after its last call; None = never.
    pub idle_timeout: Option<Duration>,
    pub kernel: Kernel,
    /// How long the search threads spin for more work after each search
    /// before they sleep (the engine's `with_spin`).
    pub spin: Duration,
    /// How assigned ranges hold their vectors.
    pub storage: Storage,
    /// Connection count and timeouts before a connection is served.
    pub connections: ConnectionLimits,
    /// Fault injection for tests and the fault campaign: when searches are
    /// answered with made-up references.
    pub wrong_answers: WrongAnswers,
    /// Fault injection for tests: report distance 0 for every query of a
    /// linked batch while searching it, and then answer truthfully (the
    /// master must refuse the answer and drop this worker).
    pub low_reports: bool,
}

impl Default for WorkerConfig {
    fn default() -> Self {
        Self {
            listen: DEFAULT_LISTEN.parse().expect("valid default address"),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            token: None,
            insecure_no_auth: false,
            tls: None,
            max_memory: default_max_memory(),
            max_message: DEFAULT_MAX_MESSAGE,
            idle_timeout: Some(DEFAULT_IDLE_TIMEOUT),
            kernel: Kernel::detect(),
            spin: texsyn_engine::search::DEFAULT_SPIN,
            storage: Storage::Auto,
            connections: ConnectionLimits::default(),
            wrong_answers: WrongAnswers::Never,
            low_reports: false,
        }
    }
}

impl std::fmt::Debug for WorkerConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerConfig")
            .field("listen", &self.listen)
            .field("threads", &self.threads)
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("insecure_no_auth", &self.insecure_no_auth)
            .field("tls", &self.tls)
            .field("max_memory", &self.max_memory)
            .field("max_message", &self.max_message)
            .field("idle_timeout", &self.idle_timeout)
            .field("kernel", &self.kernel)
            .field("spin", &self.spin)
            .field("storage", &self.storage)
            .field("connections", &self.connections)
            .field("wrong_answers", &self.wrong_answers)
            .field("low_reports", &self.low_reports)
            .finish()
    }
}

impl WorkerConfig {
    /// Refuses to serve `addr` when it is reachable from other machines and
    /// no token guards it, unless `--insecure-no-auth` says so.
    pub fn check_exposure(&self, addr: SocketAddr) -> anyhow::Result<()> {
        if self.token.is_none() && !addr.ip().is_loopback() && !self.insecure_no_auth {
            bail!(
                "refusing to listen on {addr} without a token: anyone who can reach it could use this worker; give --token-file FILE (or --token-stdin), listen on 127.0.0.1, or pass --insecure-no-auth on a network you trust"
            );
        }
        Ok(())
    }

    /// Rejects inconsistent or out-of-range settings, naming what to change.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.threads == 0 || self.threads > MAX_THREADS {
            bail!("--threads {} must be in 1..={MAX_THREADS}", self.threads);
        }
        if let Some(t) = &self.token {
            texsyn_proto::auth::check_token(t)?;
        }
        self.check_exposure(self.listen)?;
        if let Some(tls) = &self.tls {
            if tls.cert_pem.is_empty() || tls.key_pem.is_empty() {
                bail!("TLS needs both a certificate and a key; one of them is empty");
            }
        }
        if !(MIN_MAX_MESSAGE..=MAX_MAX_MESSAGE).contains(&self.max_message) {
            bail!(
                "--max-message {} must be in {MIN_MAX_MESSAGE}..={MAX_MAX_MESSAGE} bytes",
                self.max_message
            );
        }
        if self.max_memory < MIN_MAX_MEMORY {
            bail!(
                "--max-memory {} is below the minimum of {MIN_MAX_MEMORY} bytes",
                self.max_memory
            );
        }
        let c = &self.connections;
        if c.max_connections == 0 || c.max_connections > MAX_CONNECTIONS {
            bail!(
                "--max-connections {} must be in 1..={MAX_CONNECTIONS}",
                c.max_connections
            );
        }
        if c.first_byte.is_zero() || c.authenticate.is_zero() {
            bail!("the connection timeouts must be positive");
        }
        if self.idle_timeout == Some(Duration::ZERO) {
            bail!("the idle timeout must be positive (None = never)");
        }
        self.kernel.check()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_loopback() {
        let c = WorkerConfig::default();
        c.validate().unwrap();
        assert!(c.listen.ip().is_loopback());
    }

    #[test]
    fn bad_settings_are_rejected() {
        let bad = [
            WorkerConfig {
                threads: 0,
                ..Default::default()
            },
            WorkerConfig {
                token: Some("has space".into()),
                ..Default::default()
            },
            WorkerConfig {
                max_message: 10,
                ..Default::default()
            },
            WorkerConfig {
                max_memory: 10,
                ..Default::default()
            },
            WorkerConfig {
                idle_timeout: Some(Duration::ZERO),
                ..Default::default()
            },
            WorkerConfig {
                listen: "0.0.0.0:7878".parse().unwrap(),
                ..Default::default()
            },
            WorkerConfig {
                listen: "[::]:7878".parse().unwrap(),
                ..Default::default()
            },
        ];
        for c in bad {
            assert!(c.validate().is_err(), "{c:?}");
        }
    }

    #[test]
    fn public_addresses_need_a_token_or_an_explicit_opt_out() {
        let public = "10.1.2.3:7878".parse().unwrap();
        let open = WorkerConfig {
            listen: public,
            ..Default::default()
        };
        let e = open.validate().unwrap_err().to_string();
        assert!(
            e.contains("--insecure-no-auth") && e.contains("--token-file"),
            "{e}"
        );
        WorkerConfig {
            token: Some("abcdefghijklmnop".into()),
            ..open.clone()
        }
        .validate()
        .unwrap();
        WorkerConfig {
            insecure_no_auth: true,
            ..open
        }
        .validate()
        .unwrap();
    }

    #[test]
    fn debug_redacts_secrets() {
        let c = WorkerConfig {
            token: Some("s3cret".into()),
            ..Default::default()
        };
        assert!(!format!("{c:?}").contains("s3cret"));
    }
}
