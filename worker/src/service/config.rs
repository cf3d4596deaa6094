//! The worker's validated configuration.

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context};

use texsyn_engine::{Kernel, Storage};

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

/// A PEM certificate chain and private key for TLS.
#[derive(Clone)]
pub struct TlsIdentity {
    pub cert_pem: Vec<u8>,
    pub key_pem: Vec<u8>,
}

impl TlsIdentity {
    /// Reads the PEM files.
    pub fn from_files(cert: &Path, key: &Path) -> anyhow::Result<Self> {
        let cert_pem = std::fs::read(cert)
            .with_context(|| format!("cannot read the TLS certificate {}", cert.display()))?;
        let key_pem = std::fs::read(key)
            .with_context(|| format!("cannot read the TLS key {}", key.display()))?;
        Ok(Self { cert_pem, key_pem })
    }
}

impl std::fmt::Debug for TlsIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TlsIdentity")
            .field("cert_pem", &format_args!("{} bytes", self.cert_pem.len()))
            .field("key_pem", &"<redacted>")
            .finish()
    }
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
    pub tls: Option<TlsIdentity>,
    /// Most bytes one job may hold (level images, positions and vectors).
    pub max_memory: u64,
    /// Largest gRPC message decoded or encoded, in bytes.
    pub max_message: usize,
    /// Free a job this long after its last call; None = never.
    pub idle_timeout: Option<Duration>,
    pub kernel: Kernel,
    /// How assigned ranges hold their vectors.
    pub storage: Storage,
}

impl Default for WorkerConfig {
    fn default() -> Self {
        Self {
            listen: DEFAULT_LISTEN.parse().expect("valid default address"),
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            token: None,
            tls: None,
            max_memory: default_max_memory(),
            max_message: DEFAULT_MAX_MESSAGE,
            idle_timeout: Some(DEFAULT_IDLE_TIMEOUT),
            kernel: Kernel::detect(),
            storage: Storage::Auto,
        }
    }
}

impl std::fmt::Debug for WorkerConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerConfig")
            .field("listen", &self.listen)
            .field("threads", &self.threads)
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("tls", &self.tls)
            .field("max_memory", &self.max_memory)
            .field("max_message", &self.max_message)
            .field("idle_timeout", &self.idle_timeout)
            .field("kernel", &self.kernel)
            .field("storage", &self.storage)
            .finish()
    }
}

/// Three quarters of the physical memory (from /proc/meminfo), or 4 GiB where
/// that cannot be read.
pub fn default_max_memory() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("MemTotal:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map(|kb| kb.saturating_mul(1024));
    match total {
        Some(t) if t > 0 => t / 4 * 3,
        _ => 4 << 30,
    }
}

impl WorkerConfig {
    /// Rejects inconsistent or out-of-range settings, naming what to change.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.threads == 0 || self.threads > MAX_THREADS {
            bail!("--threads {} must be in 1..={MAX_THREADS}", self.threads);
        }
        if let Some(t) = &self.token {
            texsyn_proto::auth::check_token(t)?;
        }
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
        ];
        for c in bad {
            assert!(c.validate().is_err(), "{c:?}");
        }
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
