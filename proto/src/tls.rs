//! Worker addresses and client-side TLS, shared by the master and
//! `texsyn-worker health` (ARCHITECTURE §4.4): the address parser (`host:port`,
//! `http://host:port`, `https://host:port`), the client TLS flags and the one
//! place they become a tonic [`ClientTlsConfig`] and [`Endpoint`].
//!
//! Which transport a worker gets:
//! - `https://host:port`: TLS, verified with `--tls-ca` or else the system CA bundle;
//! - `http://host:port`: plaintext; an error when a TLS flag is also given;
//! - `host:port`: TLS when any TLS flag is given, plaintext otherwise.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, ensure, Context};
use tonic::transport::{Certificate, ClientTlsConfig, Endpoint, Identity};

/// The transport an address asks for with its scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// `http://`
    Plain,
    /// `https://`
    Tls,
}

/// A checked worker address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WorkerAddress {
    /// The scheme the user wrote, if any.
    pub scheme: Option<Scheme>,
    /// Host name or IP address (IPv6 in brackets).
    pub host: String,
    pub port: u16,
}

const FORMS: &str = "write host:port, https://host:port (TLS) or http://host:port (plaintext)";

/// Parses `host:port`, `[v6]:port`, `http://host:port` or `https://host:port`
/// (a single trailing `/` is allowed). Other schemes, paths, queries and user
/// names are refused.
pub fn parse_address(address: &str) -> anyhow::Result<WorkerAddress> {
    let a = address.trim();
    let (scheme, rest) = match a.split_once("://") {
        None => (None, a),
        Some((s, rest)) => match s.to_ascii_lowercase().as_str() {
            "http" => (Some(Scheme::Plain), rest),
            "https" => (Some(Scheme::Tls), rest),
            _ => bail!("worker address '{address}' has the scheme '{s}://', which texsyn does not speak; {FORMS}"),
        },
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    ensure!(
        !rest.contains(['/', '?', '#', '@']),
        "worker address '{address}' has a path, query or user name; {FORMS}"
    );
    let (host, port) = rest.rsplit_once(':').with_context(|| {
        format!("worker address '{address}' is not host:port, e.g. 192.168.1.20:7878")
    })?;
    let port: u16 = port
        .parse()
        .with_context(|| format!("port '{port}' of worker address '{address}' is not 1..=65535"))?;
    ensure!(
        port != 0,
        "worker address '{address}' has port 0; give the port the worker printed"
    );
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    ensure!(
        !bare.is_empty()
            && bare
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | ':' | '_')),
        "host '{host}' of worker address '{address}' is not a host name or IP address"
    );
    Ok(WorkerAddress {
        scheme,
        host: host.to_string(),
        port,
    })
}

/// The client TLS flags of `texsyn` (cluster runs, `cluster status`) and
/// `texsyn-worker health`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct TlsArgs {
    /// CA certificate (PEM) that signed the workers' certificates; turns TLS on
    /// for host:port addresses (https:// addresses without it use the system CAs).
    #[arg(long, value_name = "FILE")]
    pub tls_ca: Option<PathBuf>,
    /// Name the workers' certificates must carry, instead of the host of each
    /// address (e.g. when connecting by IP address); turns TLS on.
    #[arg(long, value_name = "NAME")]
    pub tls_domain: Option<String>,
    /// Client certificate (PEM) for workers that require one (mutual TLS); needs --tls-client-key.
    #[arg(long, value_name = "FILE")]
    pub tls_client_cert: Option<PathBuf>,
    /// Private key (PEM) of --tls-client-cert.
    #[arg(long, value_name = "FILE")]
    pub tls_client_key: Option<PathBuf>,
}

impl TlsArgs {
    /// True when any TLS flag is given.
    pub fn any(&self) -> bool {
        self.tls_ca.is_some()
            || self.tls_domain.is_some()
            || self.tls_client_cert.is_some()
            || self.tls_client_key.is_some()
    }

    /// Reads and checks the files.
    pub fn load(&self) -> anyhow::Result<ClientTls> {
        let ca_pem = self
            .tls_ca
            .as_deref()
            .map(|p| read_pem(p, "--tls-ca", CERT))
            .transpose()?;
        let identity = match (&self.tls_client_cert, &self.tls_client_key) {
            (Some(c), Some(k)) => Some((
                read_pem(c, "--tls-client-cert", CERT)?,
                read_pem(k, "--tls-client-key", KEY)?,
            )),
            (None, None) => None,
            (Some(_), None) => {
                bail!("--tls-client-cert needs --tls-client-key FILE with its private key")
            }
            (None, Some(_)) => {
                bail!("--tls-client-key needs --tls-client-cert FILE with its certificate")
            }
        };
        if let Some(d) = &self.tls_domain {
            ensure!(
                !d.is_empty()
                    && d.chars()
                        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | ':' | '_')),
                "--tls-domain '{d}' is not a host name or IP address"
            );
        }
        Ok(ClientTls {
            ca_pem,
            domain: self.tls_domain.clone(),
            identity,
        })
    }
}

const CERT: &str = "-----BEGIN CERTIFICATE-----";
const KEY: &str = "PRIVATE KEY-----";

/// Largest PEM file read (a CA bundle is a few hundred KiB).
const MAX_PEM: u64 = 16 << 20;

/// Reads a PEM file of `flag` and checks that it holds a `marker` block.
pub fn read_pem(path: &Path, flag: &str, marker: &str) -> anyhow::Result<Vec<u8>> {
    let len = std::fs::metadata(path)
        .with_context(|| format!("cannot read {flag} {}", path.display()))?
        .len();
    ensure!(
        len <= MAX_PEM,
        "{flag} {} is {len} bytes; expected a PEM file",
        path.display()
    );
    let pem =
        std::fs::read(path).with_context(|| format!("cannot read {flag} {}", path.display()))?;
    ensure!(
        String::from_utf8_lossy(&pem).contains(marker),
        "{flag} {} is not a PEM file with a '{}' block",
        path.display(),
        marker.trim_matches('-')
    );
    Ok(pem)
}

/// Reads a PEM certificate file (`BEGIN CERTIFICATE`) of `flag`.
pub fn read_cert_pem(path: &Path, flag: &str) -> anyhow::Result<Vec<u8>> {
    read_pem(path, flag, CERT)
}

/// Reads a PEM private key file of `flag`.
pub fn read_key_pem(path: &Path, flag: &str) -> anyhow::Result<Vec<u8>> {
    read_pem(path, flag, KEY)
}

/// Client TLS settings, read from [`TlsArgs`].
#[derive(Clone, Default, PartialEq, Eq)]
pub struct ClientTls {
    /// PEM CA certificates that verify the workers (None: the system CAs).
    pub ca_pem: Option<Vec<u8>>,
    /// Server name override.
    pub domain: Option<String>,
    /// Client certificate chain and key (PEM), for mutual TLS.
    pub identity: Option<(Vec<u8>, Vec<u8>)>,
}

impl std::fmt::Debug for ClientTls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClientTls")
            .field("ca", &self.ca_pem.is_some())
            .field("domain", &self.domain)
            .field("client_cert", &self.identity.is_some())
            .finish()
    }
}

/// Files where Linux distributions keep the system CA bundle.
const SYSTEM_BUNDLES: &[&str] = &[
    "/etc/ssl/certs/ca-certificates.crt",
    "/etc/pki/tls/certs/ca-bundle.crt",
    "/etc/pki/ca-trust/extracted/pem/tls-ca-bundle.pem",
    "/etc/ssl/ca-bundle.pem",
    "/etc/ssl/cert.pem",
];

/// The system CA bundle: `$SSL_CERT_FILE` when set, else the first of the
/// usual files that holds a certificate.
pub fn system_roots() -> anyhow::Result<Vec<u8>> {
    if let Some(f) = std::env::var_os("SSL_CERT_FILE") {
        return read_pem(Path::new(&f), "SSL_CERT_FILE", CERT);
    }
    for f in SYSTEM_BUNDLES {
        if let Ok(pem) = read_pem(Path::new(f), "the system CA bundle", CERT) {
            return Ok(pem);
        }
    }
    bail!(
        "no system CA bundle found (looked at {})",
        SYSTEM_BUNDLES.join(", ")
    )
}

impl ClientTls {
    /// True when any TLS option is set: `host:port` addresses then use TLS.
    pub fn any(&self) -> bool {
        self.ca_pem.is_some() || self.domain.is_some() || self.identity.is_some()
    }

    /// Whether `addr` is reached over TLS; an error when its scheme and the
    /// options disagree.
    pub fn use_tls(&self, addr: &WorkerAddress, written: &str) -> anyhow::Result<bool> {
        match addr.scheme {
            Some(Scheme::Tls) => Ok(true),
            Some(Scheme::Plain) if self.any() => bail!(
                "worker address '{written}' asks for plaintext (http://) but TLS options are given; write https://{}:{} or {}:{} to use TLS, or drop the --tls-* options",
                addr.host, addr.port, addr.host, addr.port
            ),
            Some(Scheme::Plain) => Ok(false),
            None => Ok(self.any()),
        }
    }

    /// Checks up front that every address can be reached as its scheme and
    /// these options say (for https:// without --tls-ca: that a system CA
    /// bundle exists).
    pub fn check(&self, addresses: &[&str]) -> anyhow::Result<()> {
        let mut roots_checked = false;
        for a in addresses {
            let addr = parse_address(a)?;
            if self.use_tls(&addr, a)? && self.ca_pem.is_none() && !roots_checked {
                system_roots().map_err(|e| {
                    anyhow::anyhow!(
                        "worker address '{a}' needs TLS, but {e:#}; give --tls-ca FILE with the CA that signed the worker's certificate"
                    )
                })?;
                roots_checked = true;
            }
        }
        Ok(())
    }

    /// The tonic TLS configuration for a worker at `host`.
    pub fn config(&self, host: &str) -> anyhow::Result<ClientTlsConfig> {
        let ca = match &self.ca_pem {
            Some(p) => p.clone(),
            None => system_roots()
                .context("give --tls-ca FILE with the CA that signed the worker's certificate")?,
        };
        let domain = self.domain.clone().unwrap_or_else(|| {
            host.trim_start_matches('[')
                .trim_end_matches(']')
                .to_string()
        });
        let mut c = ClientTlsConfig::new()
            .ca_certificate(Certificate::from_pem(ca))
            .domain_name(domain)
            .timeout(Duration::from_secs(10));
        if let Some((cert, key)) = &self.identity {
            c = c.identity(Identity::from_pem(cert, key));
        }
        Ok(c)
    }

    /// An endpoint for `address` (not yet connected): TLS as [`Self::use_tls`]
    /// decides, a connect timeout of `connect_timeout`.
    pub fn endpoint(&self, address: &str, connect_timeout: Duration) -> anyhow::Result<Endpoint> {
        let addr = parse_address(address)?;
        let tls = self.use_tls(&addr, address)?;
        let scheme = if tls { "https" } else { "http" };
        let mut e = Endpoint::from_shared(format!("{scheme}://{}:{}", addr.host, addr.port))
            .with_context(|| format!("'{address}' is not a worker address"))?
            .connect_timeout(connect_timeout);
        if tls {
            e = e
                .tls_config(self.config(&addr.host)?)
                .map_err(|e| anyhow::anyhow!("{}", error_chain(&e)))
                .context("invalid TLS options (--tls-ca, --tls-client-cert, --tls-client-key, --tls-domain)")?;
        }
        Ok(e)
    }
}

/// An error and its sources on one line, each text once.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = e.to_string();
    let mut src = e.source();
    while let Some(s) = src {
        let text = s.to_string();
        if !msg.contains(&text) {
            msg = format!("{msg}: {text}");
        }
        src = s.source();
    }
    msg
}

/// How a connection was made, for [`hint`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Used {
    Plain,
    Tls,
    /// TLS with a client certificate.
    MutualTls,
}

/// What to do about a connection or first-call error text, when it looks
/// like a TLS mismatch.
pub fn hint(text: &str, used: Used) -> Option<&'static str> {
    let t = text.to_ascii_lowercase();
    let has = |words: &[&str]| words.iter().any(|w| t.contains(w));
    if has(&["unknownissuer", "unknown issuer"]) {
        Some("the worker's certificate is not signed by a CA this side trusts: give --tls-ca FILE with the CA that signed it")
    } else if has(&["notvalidforname", "not valid for name"]) {
        Some("the worker's certificate does not name this host: give --tls-domain NAME with a name it carries")
    } else if has(&["certificaterequired", "certificate required"]) {
        Some("the worker requires a client certificate: give --tls-client-cert FILE and --tls-client-key FILE")
    } else if has(&[
        "badcertificate",
        "bad certificate",
        "unknownca",
        "unknown ca",
        "decrypterror",
    ]) {
        Some("the worker refused this client certificate: give one signed by the CA of its --tls-client-ca")
    } else if has(&[
        "invalidcontenttype",
        "invalid content type",
        "corrupt message",
    ]) {
        Some("the worker does not speak TLS: write http://host:port and drop the --tls-* options, or start the worker with --tls-cert and --tls-key")
    } else if has(&[
        "h2 protocol error",
        "connection reset",
        "broken pipe",
        "frame with invalid size",
        "connection closed",
        // hyper's word when the peer hung up before the HTTP/2 handshake
        // finished, as a TLS worker does on a plaintext preface.
        "connection was not ready",
    ]) {
        Some(match used {
            Used::Plain => "if the worker serves TLS, write https://host:port or give --tls-ca FILE",
            Used::Tls => "the worker closed the TLS connection: if it requires client certificates (--tls-client-ca), give --tls-client-cert FILE and --tls-client-key FILE",
            Used::MutualTls => "the worker closed the TLS connection: it may not accept this client certificate; give one signed by the CA of its --tls-client-ca",
        })
    } else {
        None
    }
}

impl ClientTls {
    /// `text` (an error of a connection to `address`), followed by its
    /// [`hint`] when there is one.
    pub fn explain(&self, address: &str, text: String) -> String {
        let used = match parse_address(address).map(|a| self.use_tls(&a, address)) {
            Ok(Ok(true)) if self.identity.is_some() => Used::MutualTls,
            Ok(Ok(true)) => Used::Tls,
            _ => Used::Plain,
        };
        match hint(&text, used) {
            Some(h) => format!("{text} ({h})"),
            None => text,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_and_schemes() {
        let a = parse_address("127.0.0.2:7878").unwrap();
        assert_eq!(
            (a.scheme, a.host.as_str(), a.port),
            (None, "127.0.0.2", 7878)
        );
        let a = parse_address("[::1]:80").unwrap();
        assert_eq!((a.host.as_str(), a.port), ("[::1]", 80));
        let a = parse_address("https://render-1.lan:443/").unwrap();
        assert_eq!(
            (a.scheme, a.host.as_str(), a.port),
            (Some(Scheme::Tls), "render-1.lan", 443)
        );
        let a = parse_address("HTTP://10.0.0.1:1").unwrap();
        assert_eq!(a.scheme, Some(Scheme::Plain));
        for bad in [
            "",
            "host",
            "host:",
            "host:0",
            "host:99999",
            ":80",
            "a b:80",
            "h/x:1",
            "grpc://h:1",
            "ftp://h:1",
            "https://h:1/path",
            "https://h:1//",
            "http://u@h:1",
            "https://h:1?x=1",
            "https://",
            "://h:1",
        ] {
            assert!(parse_address(bad).is_err(), "{bad}");
        }
        let e = parse_address("grpc://h:1").unwrap_err().to_string();
        assert!(
            e.contains("grpc://") && e.contains("https://host:port"),
            "{e}"
        );
        let e = parse_address("https://h:1/x").unwrap_err().to_string();
        assert!(e.contains("path"), "{e}");
    }

    #[test]
    fn scheme_and_options_decide_tls() {
        let plain = ClientTls::default();
        let ca = ClientTls {
            ca_pem: Some(b"x".to_vec()),
            ..Default::default()
        };
        let p = |s| parse_address(s).unwrap();
        assert!(!plain.use_tls(&p("h:1"), "h:1").unwrap());
        assert!(plain.use_tls(&p("https://h:1"), "").unwrap());
        assert!(!plain.use_tls(&p("http://h:1"), "").unwrap());
        assert!(ca.use_tls(&p("h:1"), "").unwrap());
        assert!(ca.use_tls(&p("https://h:1"), "").unwrap());
        let e = ca.use_tls(&p("http://h:1"), "http://h:1").unwrap_err();
        assert!(e.to_string().contains("https://h:1"), "{e}");
        assert!(ca.check(&["http://h:1"]).is_err());
        assert!(plain.check(&["h:1", "http://h:2"]).is_ok());
    }

    #[test]
    fn hints_name_the_fix() {
        assert!(hint("invalid peer certificate: UnknownIssuer", Used::Tls)
            .unwrap()
            .contains("--tls-ca"));
        assert!(hint("received fatal alert: CertificateRequired", Used::Tls)
            .unwrap()
            .contains("--tls-client-cert"));
        assert!(hint("corrupt message", Used::Tls)
            .unwrap()
            .contains("http://"));
        assert!(hint("connection closed", Used::Plain)
            .unwrap()
            .contains("https://"));
        assert!(hint(
            "Cancelled: operation was canceled: transport error: operation was canceled: connection was not ready",
            Used::Plain
        )
        .unwrap()
        .contains("https://"));
        assert!(hint("connection closed", Used::Tls)
            .unwrap()
            .contains("--tls-client-cert"));
        assert!(hint("connection closed", Used::MutualTls)
            .unwrap()
            .contains("--tls-client-ca"));
        assert_eq!(hint("Unavailable: nothing", Used::Tls), None);
        let ca = ClientTls {
            ca_pem: Some(b"x".to_vec()),
            ..Default::default()
        };
        let e = ca.explain("h:1", "connection closed".into());
        assert!(e.contains("--tls-client-cert"), "{e}");
        let e = ClientTls::default().explain("h:1", "connection closed".into());
        assert!(e.contains("https://"), "{e}");
    }
}
