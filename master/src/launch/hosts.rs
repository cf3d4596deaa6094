//! Where the workers are: `--workers host:port,...`, a hosts file (TOML) and the
//! token files that go with them (ARCHITECTURE §4.2, §4.4).
//!
//! ```toml
//! # hosts.toml
//! [[worker]]
//! address = "192.168.1.20:7878"
//! token_file = "/etc/texsyn/token"   # optional; default: --token-file
//!
//! [[worker]]
//! address = "render2.lan:7878"
//! ```

use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use texsyn_proto::auth::read_token_file;

use texsyn_proto::tls::{parse_address, Scheme};

use crate::cluster::{split_address, WorkerSpec};

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct HostsFile {
    #[serde(default)]
    worker: Vec<HostEntry>,
}

/// One `[[worker]]` entry; an unknown key (e.g. the typo `ssh_option`) is an
/// error naming the key.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct HostEntry {
    address: String,
    token_file: Option<PathBuf>,
    /// `user@host` to launch the worker over ssh (`--launch`).
    ssh: Option<String>,
    /// Path of `texsyn-worker` on that host (default: `texsyn-worker` on its PATH).
    binary: Option<String>,
    /// Search threads of the launched worker (default: the host's cores).
    threads: Option<usize>,
    /// Port the launched worker listens on (default: the address's port, else any free port).
    port: Option<u16>,
    /// Extra options for the ssh client, e.g. `["-F", "/path/ssh_config"]`.
    #[serde(default)]
    ssh_options: Vec<String>,
    /// TLS certificate chain of the launched worker (a path on that host).
    tls_cert: Option<String>,
    /// TLS private key of the launched worker (a path on that host).
    tls_key: Option<String>,
    /// CA whose client certificates the launched worker requires (mutual TLS; a path on that host).
    tls_client_ca: Option<String>,
}

/// Largest hosts file read (it is a short list).
const MAX_HOSTS_FILE: u64 = 1 << 20;

/// A host on which `--launch` starts a worker over ssh.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LaunchSpec {
    /// Host (name or IP) the worker listens on and the master connects to.
    pub host: String,
    /// Port to listen on; 0 = any free port (read from the worker's listening line).
    pub port: u16,
    /// ssh target, `user@host`.
    pub ssh: String,
    /// `texsyn-worker` on the remote host.
    pub binary: String,
    pub threads: Option<usize>,
    pub ssh_options: Vec<String>,
    /// The launched worker serves TLS with these files (paths on that host).
    pub tls: Option<LaunchTls>,
}

/// TLS files of a launched worker, as paths on its host.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LaunchTls {
    pub cert: String,
    pub key: String,
    /// Client CA: the worker requires client certificates signed by it.
    pub client_ca: Option<String>,
}

/// Reads a hosts file. A worker's `token_file` (relative paths are relative to
/// the hosts file) overrides `default_token`.
pub fn read_hosts_file(path: &Path, default_token: Option<&str>) -> Result<Vec<WorkerSpec>> {
    Ok(read_hosts_file_launch(path, default_token, false)?.0)
}

/// Reads a hosts file; with `launch`, entries with `ssh = "user@host"` are
/// returned as hosts to launch (their `address` may be a bare host), the others
/// as running workers.
pub fn read_hosts_file_launch(
    path: &Path,
    default_token: Option<&str>,
    launch: bool,
) -> Result<(Vec<WorkerSpec>, Vec<LaunchSpec>)> {
    let meta = std::fs::metadata(path)
        .with_context(|| format!("cannot read the hosts file {}", path.display()))?;
    ensure!(
        meta.len() <= MAX_HOSTS_FILE,
        "the hosts file {} is {} bytes; a hosts file is a short TOML list of workers",
        path.display(),
        meta.len()
    );
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the hosts file {}", path.display()))?;
    let parsed: HostsFile = toml::from_str(&text).map_err(|e| {
        let line = e
            .span()
            .map(|r| format!(" (line {})", text.as_bytes()[..r.start.min(text.len())].iter().filter(|&&b| b == b'\n').count() + 1))
            .unwrap_or_default();
        anyhow::anyhow!(
            "the hosts file {}{line}: {}; it must be a list of [[worker]] entries with address = \"host:port\" and the optional keys token_file, ssh, binary, threads, port, ssh_options",
            path.display(),
            texsyn_proto::cli::one_line(e.message())
        )
    })?;
    if parsed.worker.is_empty() {
        bail!(
            "the hosts file {} lists no workers; add [[worker]] entries with address = \"host:port\"",
            path.display()
        );
    }
    let base = path.parent().unwrap_or(Path::new("."));
    let mut launches = Vec::new();
    let mut running = Vec::new();
    for e in parsed.worker {
        match (launch, &e.ssh) {
            (true, Some(ssh)) => launches.push(launch_spec(&e, ssh, path)?),
            _ => running.push(entry_spec(e, path, base, default_token)?),
        }
    }
    Ok((running, launches))
}

/// A `--launch` entry: the host to start a worker on over `ssh`.
fn launch_spec(e: &HostEntry, ssh: &str, path: &Path) -> Result<LaunchSpec> {
    ensure!(
        !ssh.trim().is_empty() && !ssh.starts_with('-') && !ssh.contains(char::is_whitespace),
        "ssh target '{ssh}' in the hosts file {} is not user@host",
        path.display()
    );
    let (host, port, scheme) = match parse_address(&e.address) {
        Ok(a) => (a.host, a.port, a.scheme),
        Err(_) => {
            let h = e.address.trim().trim_end_matches('/').to_string();
            let a = parse_address(&format!("{h}:1")).with_context(|| {
                format!(
                    "address '{}' in the hosts file {}",
                    e.address,
                    path.display()
                )
            })?;
            (a.host, 0, a.scheme)
        }
    };
    if let Some(t) = e.threads {
        ensure!(t > 0, "threads = 0 for {} in {}", e.address, path.display());
    }
    let tls = match (&e.tls_cert, &e.tls_key) {
        (Some(cert), Some(key)) => Some(LaunchTls {
            cert: cert.clone(),
            key: key.clone(),
            client_ca: e.tls_client_ca.clone(),
        }),
        (None, None) => None,
        _ => bail!(
            "the [[worker]] entry {} in the hosts file {} has only one of tls_cert and tls_key; give both (paths on that host)",
            e.address,
            path.display()
        ),
    };
    ensure!(
        tls.is_some() || e.tls_client_ca.is_none(),
        "the [[worker]] entry {} in the hosts file {} has tls_client_ca without tls_cert and tls_key; mutual TLS needs both",
        e.address,
        path.display()
    );
    ensure!(
        !(tls.is_some() && scheme == Some(Scheme::Plain)),
        "the [[worker]] entry {} in the hosts file {} is http:// but has tls_cert; write https:// or drop tls_cert and tls_key",
        e.address,
        path.display()
    );
    ensure!(
        tls.is_some() || scheme != Some(Scheme::Tls),
        "the [[worker]] entry {} in the hosts file {} is https:// but has no tls_cert and tls_key for the launched worker; add them (paths on that host)",
        e.address,
        path.display()
    );
    Ok(LaunchSpec {
        host,
        port: e.port.unwrap_or(port),
        ssh: ssh.to_string(),
        binary: e.binary.clone().unwrap_or_else(|| "texsyn-worker".into()),
        threads: e.threads,
        ssh_options: e.ssh_options.clone(),
        tls,
    })
}

/// A running worker's entry, with its token.
fn entry_spec(
    e: HostEntry,
    path: &Path,
    base: &Path,
    default_token: Option<&str>,
) -> Result<WorkerSpec> {
    split_address(&e.address).with_context(|| format!("in the hosts file {}", path.display()))?;
    ensure!(
        e.tls_cert.is_none() && e.tls_key.is_none() && e.tls_client_ca.is_none(),
        "the [[worker]] entry {} in the hosts file {} has tls_cert, tls_key or tls_client_ca, which only a launched worker (ssh = ..., --launch) uses; for a running worker give --tls-ca and an https:// address",
        e.address,
        path.display()
    );
    let token = match &e.token_file {
        Some(f) => Some(read_token_file(&base.join(f))?),
        None => default_token.map(str::to_string),
    };
    Ok(WorkerSpec::new(e.address, token))
}

/// Parses a `--workers a:1,b:2` list (empty entries are ignored).
pub fn parse_worker_list(list: &[String], token: Option<&str>) -> Result<Vec<WorkerSpec>> {
    let mut out = Vec::new();
    for item in list.iter().flat_map(|s| s.split(',')) {
        let item = item.trim();
        if item.is_empty() {
            continue;
        }
        split_address(item)?;
        out.push(WorkerSpec::new(item, token.map(str::to_string)));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_list_and_hosts_file() {
        let l = parse_worker_list(&["a:1, b:2".into(), "c:3".into()], Some("t")).unwrap();
        assert_eq!(l.len(), 3);
        assert_eq!(l[1].address, "b:2");
        assert_eq!(l[2].token.as_deref(), Some("t"));
        assert!(parse_worker_list(&["a:1,nope".into()], None).is_err());

        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("tok"), "s3cret\n").unwrap();
        let hosts = dir.path().join("hosts.toml");
        std::fs::write(
            &hosts,
            "[[worker]]\naddress = \"10.0.0.1:7878\"\ntoken_file = \"tok\"\n\n[[worker]]\naddress = \"10.0.0.2:7878\"\n",
        )
        .unwrap();
        let w = read_hosts_file(&hosts, Some("default")).unwrap();
        assert_eq!(w.len(), 2);
        assert_eq!(w[0].token.as_deref(), Some("s3cret"));
        assert_eq!(w[1].token.as_deref(), Some("default"));
        assert!(!format!("{w:?}").contains("s3cret"));

        for bad in [
            "",
            "[[worker]]\nadress = \"a:1\"\n",
            "[[workers]]\naddress = \"a:1\"\n",
            "[[worker]]\naddress = \"a\"\n",
            "[[worker]]\naddress = \"a:1\"\ntoken_file = \"missing\"\n",
            "not toml at all",
        ] {
            std::fs::write(&hosts, bad).unwrap();
            assert!(read_hosts_file(&hosts, None).is_err(), "{bad}");
        }
        std::fs::write(dir.path().join("empty"), "  \n").unwrap();
        assert!(read_token_file(&dir.path().join("empty")).is_err());
    }

    #[test]
    fn unknown_keys_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = dir.path().join("hosts.toml");
        for (text, key, line) in [
            (
                "[[worker]]\naddress = \"a:1\"\nssh = \"me@a\"\nssh_option = [\"-F\", \"c\"]\n",
                "ssh_option",
                4,
            ),
            ("[[worker]]\naddress = \"a:1\"\ntoken = \"x\"\n", "token", 3),
            ("port = 1\n[[worker]]\naddress = \"a:1\"\n", "port", 1),
        ] {
            std::fs::write(&hosts, text).unwrap();
            for launch in [false, true] {
                let e = format!(
                    "{:#}",
                    read_hosts_file_launch(&hosts, None, launch).unwrap_err()
                );
                assert!(e.contains(&format!("unknown field `{key}`")), "{e}");
                assert!(e.contains(&format!("(line {line})")), "{e}");
                assert!(!e.contains('\n'), "one line: {e}");
            }
        }
    }

    #[test]
    fn launch_entries() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = dir.path().join("hosts.toml");
        std::fs::write(
            &hosts,
            "[[worker]]\naddress = \"10.0.0.1:7878\"\n\n[[worker]]\naddress = \"10.0.0.2\"\nssh = \"me@10.0.0.2\"\nbinary = \"/opt/texsyn-worker\"\nthreads = 3\nssh_options = [\"-F\", \"cfg\"]\n\n[[worker]]\naddress = \"10.0.0.3:9000\"\nssh = \"10.0.0.3\"\nport = 7000\n",
        )
        .unwrap();
        let (running, launch) = read_hosts_file_launch(&hosts, None, true).unwrap();
        assert_eq!(running.len(), 1);
        assert_eq!(launch.len(), 2);
        assert_eq!(launch[0].host, "10.0.0.2");
        assert_eq!(launch[0].port, 0);
        assert_eq!(launch[0].threads, Some(3));
        assert_eq!(launch[0].ssh_options, vec!["-F", "cfg"]);
        assert_eq!(launch[1].port, 7000);
        assert_eq!(launch[1].binary, "texsyn-worker");
        // Without --launch a bare host is not a worker address.
        assert!(read_hosts_file(&hosts, None).is_err());
        std::fs::write(
            &hosts,
            "[[worker]]\naddress = \"a\"\nssh = \"-oProxyCommand=x\"\n",
        )
        .unwrap();
        assert!(read_hosts_file_launch(&hosts, None, true).is_err());
    }

    #[test]
    fn launch_entries_with_tls() {
        let dir = tempfile::tempdir().unwrap();
        let hosts = dir.path().join("hosts.toml");
        let entry = |extra: &str| {
            format!(
                "[[worker]]\naddress = \"https://10.0.0.2:7000\"\nssh = \"me@10.0.0.2\"\n{extra}"
            )
        };
        std::fs::write(
            &hosts,
            entry("tls_cert = \"/etc/t/c.pem\"\ntls_key = \"/etc/t/k.pem\"\ntls_client_ca = \"/etc/t/ca.pem\"\n"),
        )
        .unwrap();
        let (_, launch) = read_hosts_file_launch(&hosts, None, true).unwrap();
        assert_eq!(
            (launch[0].host.as_str(), launch[0].port),
            ("10.0.0.2", 7000)
        );
        let tls = launch[0].tls.as_ref().unwrap();
        assert_eq!(tls.cert, "/etc/t/c.pem");
        assert_eq!(tls.client_ca.as_deref(), Some("/etc/t/ca.pem"));
        for bad in [
            entry(""),
            entry("tls_cert = \"/c\"\n"),
            entry("tls_client_ca = \"/ca\"\n"),
            entry("tls_cert = \"/c\"\ntls_key = \"/k\"\n").replace("https://", "http://"),
            "[[worker]]\naddress = \"a:1\"\ntls_cert = \"/c\"\ntls_key = \"/k\"\n".into(),
        ] {
            std::fs::write(&hosts, &bad).unwrap();
            assert!(read_hosts_file_launch(&hosts, None, true).is_err(), "{bad}");
        }
    }
}
