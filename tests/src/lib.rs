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
