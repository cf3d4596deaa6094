//! Integration tests live in `tests/tests/`. This library holds the fixtures
//! that test crates elsewhere in the workspace share with them (the worker's
//! service tests use it as a dev-dependency).

use std::path::{Path, PathBuf};
use std::process::Command;

/// A self-signed TLS certificate for `localhost` (EC P-256, one day) and its
/// key, written by `openssl` into `dir` as `cert.pem` and `key.pem`. `None`
/// where openssl is missing or fails (the caller skips its test and says so).
pub fn self_signed_certificate(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
    let made = Command::new("openssl")
        .args(["req", "-x509", "-newkey", "ec", "-pkeyopt"])
        .args(["ec_paramgen_curve:prime256v1", "-nodes", "-days", "1"])
        .args(["-subj", "/CN=localhost"])
        .args(["-addext", "subjectAltName=DNS:localhost"])
        .args(["-addext", "basicConstraints=critical,CA:FALSE", "-keyout"])
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .output();
    if made.as_ref().is_ok_and(|o| o.status.success()) {
        Some((cert, key))
    } else {
        eprintln!("skipped: openssl could not make a test certificate");
        None
    }
}

/// Test certificates made with `openssl`: a CA and a server certificate it
/// signed (for `localhost` and 127.0.0.1), a client CA and a client
/// certificate it signed, and a client certificate of another CA.
pub struct Pki {
    pub ca: PathBuf,
    pub server_cert: PathBuf,
    pub server_key: PathBuf,
    pub client_ca: PathBuf,
    pub client_cert: PathBuf,
    pub client_key: PathBuf,
    pub other_client_cert: PathBuf,
    pub other_client_key: PathBuf,
}

fn openssl(args: &[&str], dir: &Path) -> bool {
    Command::new("openssl")
        .args(args)
        .current_dir(dir)
        .output()
        .is_ok_and(|o| o.status.success())
}

/// A CA `NAME.pem`/`NAME.key` in `dir`.
fn make_ca(dir: &Path, name: &str) -> bool {
    openssl(
        &[
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-days",
            "1",
            "-subj",
            &format!("/CN=texsyn test {name}"),
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
            "-keyout",
            &format!("{name}.key"),
            "-out",
            &format!("{name}.pem"),
        ],
        dir,
    )
}

/// A leaf `NAME.pem`/`NAME.key` signed by the CA `ca`, with the extensions `ext`.
fn make_leaf(dir: &Path, name: &str, ca: &str, ext: &str, serial: &str) -> bool {
    let ext_file = format!("{name}.ext");
    std::fs::write(dir.join(&ext_file), ext).is_ok()
        && openssl(
            &[
                "req",
                "-new",
                "-newkey",
                "ec",
                "-pkeyopt",
                "ec_paramgen_curve:prime256v1",
                "-nodes",
                "-subj",
                &format!("/CN={name}"),
                "-keyout",
                &format!("{name}.key"),
                "-out",
                &format!("{name}.csr"),
            ],
            dir,
        )
        && openssl(
            &[
                "x509",
                "-req",
                "-in",
                &format!("{name}.csr"),
                "-CA",
                &format!("{ca}.pem"),
                "-CAkey",
                &format!("{ca}.key"),
                "-set_serial",
                serial,
                "-days",
                "1",
                "-extfile",
                &ext_file,
                "-out",
                &format!("{name}.pem"),
            ],
            dir,
        )
}

/// Makes the [`Pki`] in `dir`. Where openssl is missing or fails: `None` with
/// a message on stderr (the caller skips its test), or a panic when the
/// environment variable `CI` is `true`.
pub fn test_pki(dir: &Path) -> Option<Pki> {
    let leaf = |usage: &str| {
        format!("basicConstraints=critical,CA:FALSE\nextendedKeyUsage={usage}\nsubjectAltName=DNS:localhost,IP:127.0.0.1\n")
    };
    let made = make_ca(dir, "ca")
        && make_ca(dir, "client-ca")
        && make_ca(dir, "other-ca")
        && make_leaf(dir, "server", "ca", &leaf("serverAuth"), "1")
        && make_leaf(dir, "client", "client-ca", &leaf("clientAuth"), "2")
        && make_leaf(dir, "other-client", "other-ca", &leaf("clientAuth"), "3");
    if !made {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "openssl could not make the test certificates (CI=true: not skipping)"
        );
        eprintln!("SKIP: openssl is missing or could not make the test certificates");
        return None;
    }
    let p = |f: &str| dir.join(f);
    Some(Pki {
        ca: p("ca.pem"),
        server_cert: p("server.pem"),
        server_key: p("server.key"),
        client_ca: p("client-ca.pem"),
        client_cert: p("client.pem"),
        client_key: p("client.key"),
        other_client_cert: p("other-client.pem"),
        other_client_key: p("other-client.key"),
    })
}
