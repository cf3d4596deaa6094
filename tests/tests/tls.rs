//! TLS between the master and its workers (ARCHITECTURE §4.4) with
//! real `texsyn` and `texsyn-worker` processes and certificates made by
//! `openssl`: a synthesis over TLS is bit-identical to a local one; URL
//! schemes are honoured or refused with one clear line; mutual TLS refuses a
//! client without a certificate or with one of another CA; `cluster status`
//! and `health` speak TLS. Skipped with a message where openssl is missing
//! (a failure when CI=true).

use crate::harness;

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use harness::{texture_path, Token, Worker};
use texsyn_integration::{test_pki, Pki};

fn texsyn() -> Command {
    Command::new(harness::binary("texsyn"))
}

fn texsyn_worker() -> Command {
    Command::new(harness::binary("texsyn-worker"))
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 temp path")
}

/// A TLS worker on 127.0.0.`host` with the test token; `extra` flags appended.
fn tls_worker(host: u8, pki: &Pki, token: &Token, extra: &[&str]) -> Worker {
    let mut args = vec![
        "--threads",
        "1",
        "--token-file",
        path(&token.path),
        "--tls-cert",
        path(&pki.server_cert),
        "--tls-key",
        path(&pki.server_key),
    ];
    args.extend_from_slice(extra);
    Worker::start(host, &args)
}

/// Runs `cmd`, which must end within `limit`.
fn run(cmd: &mut Command, limit: Duration) -> Output {
    let t = Instant::now();
    let out = cmd.output().expect("run");
    assert!(
        t.elapsed() < limit,
        "took {:?} (limit {limit:?}): {cmd:?}",
        t.elapsed()
    );
    out
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Fails with exit 1 and an error line on stderr containing every one of `needles`.
fn assert_fails_with(o: &Output, needles: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    let line = e
        .lines()
        .find(|l| l.contains("error:"))
        .unwrap_or_else(|| panic!("no error line: {e}"));
    for n in needles {
        assert!(line.contains(n), "'{n}' not in: {line}");
    }
}

fn assert_ok(o: &Output) {
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        stderr(o)
    );
}

/// `texsyn synth` of the brick sample with `--search` `search` into `out`.
fn synth(out: &Path, search: &str) -> Command {
    let mut c = texsyn();
    c.arg("synth")
        .arg(texture_path("brick_color_96.png"))
        .args(["--size", "96x96", "--levels", "3", "--seed", "3", "-q"])
        .args(["--search", search, "-o"])
        .arg(out);
    c
}

#[test]
fn synthesis_over_tls_is_bit_identical_to_a_local_run() {
    let dir = tempfile::tempdir().unwrap();
    let Some(pki) = test_pki(dir.path()) else {
        return;
    };
    let token = Token::new();
    let w = tls_worker(1, &pki, &token, &[]);
    let local = dir.path().join("local.png");
    assert_ok(&run(
        &mut synth(&local, "local,local,local"),
        Duration::from_secs(120),
    ));
    for (name, address) in [
        (
            "https.png",
            format!("https://127.0.0.1:{}", w.address.port()),
        ),
        ("bare.png", format!("127.0.0.1:{}", w.address.port())),
    ] {
        let out = dir.path().join(name);
        let report = dir.path().join("report.json");
        let o = run(
            synth(&out, "cluster,cluster,cluster")
                .args(["--workers", &address, "--tls-ca", path(&pki.ca)])
                .args(["--token-file", path(&token.path), "--require-cluster"])
                .arg("--report")
                .arg(&report),
            Duration::from_secs(120),
        );
        assert_ok(&o);
        assert!(
            std::fs::read(&local).unwrap() == std::fs::read(&out).unwrap(),
            "{address}: output over TLS differs from the local run"
        );
        let r: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        let workers = r["search_stats"]["cluster"]["workers"].as_array().unwrap();
        assert_eq!(workers.len(), 1, "{r:#}");
        assert!(workers[0]["queries"].as_u64().unwrap() > 0, "{r:#}");
    }
}

#[test]
fn schemes_are_honoured_or_refused_with_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let Some(pki) = test_pki(dir.path()) else {
        return;
    };
    let token = Token::new();
    let w = tls_worker(1, &pki, &token, &[]);
    let port = w.address.port();
    let out = dir.path().join("out.png");
    let limit = Duration::from_secs(30);
    let cluster = |address: &str| {
        let mut c = synth(&out, "cluster,cluster,cluster");
        c.args(["--workers", address, "--token-file", path(&token.path)])
            .arg("--require-cluster");
        c
    };
    let https = format!("https://127.0.0.1:{port}");
    let http = format!("http://127.0.0.1:{port}");

    // https:// with the system CAs only: the test CA is not among them.
    let o = run(&mut cluster(&https), limit);
    assert_fails_with(&o, &["127.0.0.1", "--tls-ca"]);
    // https:// with no CA at all (no system bundle): refused up front.
    let o = run(
        cluster(&https).env("SSL_CERT_FILE", dir.path().join("missing.pem")),
        limit,
    );
    assert_fails_with(&o, &[&https, "needs TLS", "--tls-ca FILE"]);
    // http:// to a TLS worker fails fast, pointing at https://.
    let o = run(&mut cluster(&http), limit);
    assert_fails_with(&o, &["127.0.0.1", "https://"]);
    // http:// with --tls-ca is a contradiction.
    let o = run(cluster(&http).args(["--tls-ca", path(&pki.ca)]), limit);
    assert_fails_with(&o, &[&http, &https, "--tls"]);
    // Other schemes and paths are refused.
    for bad in [
        format!("grpc://127.0.0.1:{port}"),
        format!("ftp://127.0.0.1:{port}"),
        format!("https://127.0.0.1:{port}/texsyn"),
    ] {
        let o = run(cluster(&bad).args(["--tls-ca", path(&pki.ca)]), limit);
        assert_fails_with(&o, &[&bad, "https://host:port"]);
    }
    // No output was written by any of them.
    assert!(!out.exists());

    // The same for `cluster status` and `health`.
    let o = run(
        texsyn()
            .args(["cluster", "status", "--workers", &http])
            .args(["--token-file", path(&token.path)]),
        limit,
    );
    assert_fails_with(&o, &["no worker answered"]);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("https://"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let o = run(
        texsyn_worker()
            .args(["health", "--address", &http])
            .args(["--token-file", path(&token.path)]),
        limit,
    );
    assert_fails_with(&o, &[&http, "https://"]);
    let o = run(
        texsyn_worker()
            .args(["health", "--address", &format!("grpc://127.0.0.1:{port}")])
            .args(["--token-file", path(&token.path)]),
        limit,
    );
    assert_fails_with(&o, &["grpc://"]);
}

#[test]
fn status_and_health_speak_tls() {
    let dir = tempfile::tempdir().unwrap();
    let Some(pki) = test_pki(dir.path()) else {
        return;
    };
    let token = Token::new();
    let w = tls_worker(1, &pki, &token, &[]);
    // The certificate names localhost and 127.0.0.1, not 127.0.0.5.
    let w5 = tls_worker(5, &pki, &token, &[]);
    let limit = Duration::from_secs(30);
    let bare = format!("127.0.0.1:{}", w.address.port());
    let https = format!("https://127.0.0.1:{}", w.address.port());
    let other = format!("https://127.0.0.5:{}", w5.address.port());
    for address in [&bare, &https] {
        let o = run(
            texsyn()
                .args(["cluster", "status", "--workers", address])
                .args(["--token-file", path(&token.path), "--tls-ca", path(&pki.ca)]),
            limit,
        );
        assert_ok(&o);
        let table = String::from_utf8_lossy(&o.stdout);
        assert!(
            table.contains(address.as_str()) && table.contains("ok ("),
            "{table}"
        );
        let o = run(
            texsyn_worker()
                .args(["health", "--address", address])
                .args(["--token-file", path(&token.path), "--tls-ca", path(&pki.ca)]),
            limit,
        );
        assert_ok(&o);
        assert!(String::from_utf8_lossy(&o.stdout).contains("SERVING"));
    }
    // A certificate that does not name the host: refused, --tls-domain fixes it.
    let o = run(
        texsyn_worker().args(["health", "--address", &other]).args([
            "--token-file",
            path(&token.path),
            "--tls-ca",
            path(&pki.ca),
        ]),
        limit,
    );
    assert_fails_with(&o, &["--tls-domain"]);
    let o = run(
        texsyn_worker()
            .args(["health", "--address", &other, "--tls-domain", "localhost"])
            .args(["--token-file", path(&token.path), "--tls-ca", path(&pki.ca)]),
        limit,
    );
    assert_ok(&o);
    let o = run(
        texsyn()
            .args(["cluster", "status", "--workers", &other])
            .args(["--tls-domain", "localhost", "--tls-ca", path(&pki.ca)])
            .args(["--token-file", path(&token.path)]),
        limit,
    );
    assert_ok(&o);
}

#[test]
fn mutual_tls_refuses_clients_without_the_right_certificate() {
    let dir = tempfile::tempdir().unwrap();
    let Some(pki) = test_pki(dir.path()) else {
        return;
    };
    let token = Token::new();
    let w = tls_worker(1, &pki, &token, &["--tls-client-ca", path(&pki.client_ca)]);
    let address = format!("https://127.0.0.1:{}", w.address.port());
    let limit = Duration::from_secs(30);
    let common = ["--tls-ca", path(&pki.ca), "--token-file", path(&token.path)];
    let none: [&str; 0] = [];
    let right = [
        "--tls-client-cert",
        path(&pki.client_cert),
        "--tls-client-key",
        path(&pki.client_key),
    ];
    let wrong = [
        "--tls-client-cert",
        path(&pki.other_client_cert),
        "--tls-client-key",
        path(&pki.other_client_key),
    ];
    let status = |client: &[&str]| {
        run(
            texsyn()
                .args(["cluster", "status", "--workers", &address])
                .args(common)
                .args(client),
            limit,
        )
    };
    let health = |client: &[&str]| {
        run(
            texsyn_worker()
                .args(["health", "--address", &address])
                .args(common)
                .args(client),
            limit,
        )
    };
    // No client certificate.
    let o = status(&none);
    assert_fails_with(&o, &["no worker answered"]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("--tls-client-cert"), "{table}");
    assert_fails_with(&health(&none), &[&address, "--tls-client-cert"]);
    // A client certificate of another CA.
    let o = status(&wrong);
    assert_fails_with(&o, &["no worker answered"]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("error:"), "{table}");
    let o = health(&wrong);
    assert_fails_with(&o, &[&address]);
    // The right one.
    let o = status(&right);
    assert_ok(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("ok ("));
    let o = health(&right);
    assert_ok(&o);
    assert!(String::from_utf8_lossy(&o.stdout).contains("SERVING"));
    // A synthesis with the client certificate works as well.
    let out = dir.path().join("out.png");
    let o = run(
        synth(&out, "cluster,cluster,cluster")
            .args(["--workers", &address, "--require-cluster"])
            .args(common)
            .args(right),
        Duration::from_secs(120),
    );
    assert_ok(&o);
    // A half-given client identity or a client CA without TLS is refused.
    let o = run(
        texsyn_worker()
            .args(["health", "--address", &address])
            .args(common)
            .args(&right[..2]),
        limit,
    );
    assert_fails_with(&o, &["--tls-client-cert", "--tls-client-key"]);
    let o = run(
        texsyn()
            .args(["cluster", "status", "--workers", &address])
            .args(common)
            .args(&right[2..]),
        limit,
    );
    assert_fails_with(&o, &["--tls-client-key", "--tls-client-cert"]);
    let o = run(
        texsyn_worker()
            .args(["serve", "--listen", "127.0.0.1:0", "--tls-client-ca"])
            .arg(&pki.client_ca),
        limit,
    );
    assert_fails_with(&o, &["--tls-client-ca", "--tls-cert"]);
}
