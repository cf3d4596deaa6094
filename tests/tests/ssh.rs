//! Workers launched over real ssh (`--hosts FILE --launch`): a private
//! sshd on a high port of 127.0.0.1 with generated host and client keys; 2
//! workers launched through it give output bit-identical to the local engine
//! and are gone after the run — also after the master is killed with SIGKILL.
//! Where sshd cannot be started the sshd tests say so and are skipped (under
//! `CI=true` they fail).

use crate::harness;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use harness::{planned, synth, texture_path};
use texsyn::cluster::{ClusterOptions, ClusterSearch, WorkerSpec};
use texsyn::launch::hosts::{read_hosts_file_launch, LaunchSpec};
use texsyn::launch::ssh::SshWorkers;
use texsyn::search::{SearchBackend, Strategy};
use texsyn::Output;
use texsyn_engine::Engine;

/// Side of the synthesised texture.
const SIDE: usize = 96;

fn run(strategy: Strategy, cluster: Option<ClusterSearch>) -> Output {
    let cluster = cluster.map(|c| Box::new(c) as Box<dyn SearchBackend>);
    synth(&mut planned(strategy, cluster), SIDE).unwrap()
}

/// Pids of processes whose command line contains `pattern`.
fn pgrep(pattern: &str) -> Vec<u32> {
    let out = Command::new("pgrep")
        .arg("-f")
        .arg(pattern)
        .output()
        .expect("pgrep");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.trim().parse().ok())
        .filter(|&p| p != std::process::id())
        .collect()
}

fn wait_gone(pattern: &str, within: Duration) -> Vec<u32> {
    let start = Instant::now();
    loop {
        let left = pgrep(pattern);
        if left.is_empty() || start.elapsed() > within {
            return left;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn worker_exits_when_its_stdin_closes_and_reads_the_token_from_stdin() {
    let bin = harness::binary("texsyn-worker");
    let mut child = Command::new(&bin)
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--threads",
            "1",
            "--token-stdin",
            "--exit-on-stdin-close",
        ])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    writeln!(stdin, "0123456789abcdef").unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(line.starts_with("listening on "), "{line}");
    // Still serving while stdin is open.
    std::thread::sleep(Duration::from_millis(300));
    assert!(child.try_wait().unwrap().is_none(), "exited too early");
    drop(stdin);
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(3) {
            let _ = child.kill();
            panic!("the worker did not exit within 3 s of its stdin closing");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{status}");

    // Without the flag the worker keeps serving after EOF on stdin.
    let mut child = Command::new(&bin)
        .args(["serve", "--listen", "127.0.0.1:0", "--threads", "1"])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    std::thread::sleep(Duration::from_millis(500));
    assert!(child.try_wait().unwrap().is_none());
    let _ = child.kill();
    let _ = child.wait();
}

/// A private sshd on 127.0.0.1:PORT, killed on drop.
struct Sshd {
    child: Child,
    dir: tempfile::TempDir,
    config: PathBuf,
    user: String,
}

impl Drop for Sshd {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn find(name: &str, extra: &[&str]) -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var_os("PATH")
        .map(|p| std::env::split_paths(&p).collect())
        .unwrap_or_default();
    dirs.extend(extra.iter().map(PathBuf::from));
    dirs.into_iter().map(|d| d.join(name)).find(|p| p.is_file())
}

fn keygen(keygen: &Path, path: &Path) -> Result<(), String> {
    let out = Command::new(keygen)
        .args(["-q", "-t", "ed25519", "-N", "", "-f"])
        .arg(path)
        .output()
        .map_err(|e| e.to_string())?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    Ok(())
}

/// Starts the sshd, or says why it cannot.
fn start_sshd() -> Result<Sshd, String> {
    let sshd = find("sshd", &["/usr/sbin", "/usr/local/sbin", "/sbin"]).ok_or("no sshd")?;
    let kg = find("ssh-keygen", &[]).ok_or("no ssh-keygen")?;
    find("ssh", &[]).ok_or("no ssh client")?;
    find("pgrep", &[]).ok_or("no pgrep")?;
    let dir = tempfile::Builder::new()
        .prefix("texsyn-sshd-")
        .tempdir()
        .map_err(|e| e.to_string())?;
    let d = dir.path();
    keygen(&kg, &d.join("host_key"))?;
    keygen(&kg, &d.join("client_key"))?;
    std::fs::copy(d.join("client_key.pub"), d.join("authorized_keys"))
        .map_err(|e| e.to_string())?;
    let user = Command::new("id")
        .arg("-un")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .map_err(|e| e.to_string())?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| e.to_string())?
        .port();
    let sshd_config = d.join("sshd_config");
    std::fs::write(
        &sshd_config,
        format!(
            "Port {port}\nListenAddress 127.0.0.1\nHostKey {d}/host_key\nAuthorizedKeysFile {d}/authorized_keys\n\
             PidFile {d}/sshd.pid\nUsePAM no\nStrictModes no\nPermitRootLogin yes\nPasswordAuthentication no\n\
             KbdInteractiveAuthentication no\nPubkeyAuthentication yes\nLogLevel ERROR\n",
            d = d.display()
        ),
    )
    .map_err(|e| e.to_string())?;
    // sshd wants its privilege separation directory.
    let _ = std::fs::create_dir_all("/run/sshd");
    let log = std::fs::File::create(d.join("sshd.log")).map_err(|e| e.to_string())?;
    let child = Command::new(&sshd)
        .arg("-D")
        .arg("-e")
        .arg("-f")
        .arg(&sshd_config)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", sshd.display()))?;
    let config = d.join("ssh_config");
    std::fs::write(
        &config,
        format!(
            "Host *\n  Port {port}\n  IdentityFile {d}/client_key\n  IdentitiesOnly yes\n  StrictHostKeyChecking no\n  \
             UserKnownHostsFile /dev/null\n  LogLevel ERROR\n",
            d = d.display()
        ),
    )
    .map_err(|e| e.to_string())?;
    let mut s = Sshd {
        child,
        dir,
        config,
        user,
    };
    let start = Instant::now();
    loop {
        if let Ok(Some(st)) = s.child.try_wait() {
            let log = std::fs::read_to_string(s.dir.path().join("sshd.log")).unwrap_or_default();
            return Err(format!("sshd exited ({st}): {log}"));
        }
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            break;
        }
        if start.elapsed() > Duration::from_secs(10) {
            return Err("sshd did not listen within 10 s".into());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // A real login works.
    let out = Command::new("ssh")
        .args(["-o", "BatchMode=yes", "-F"])
        .arg(&s.config)
        .arg(format!("{}@127.0.0.1", s.user))
        .arg("echo ok")
        .output()
        .map_err(|e| e.to_string())?;
    if !String::from_utf8_lossy(&out.stdout).contains("ok") {
        return Err(format!(
            "ssh login to the test sshd failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let _ = &mut s;
    Ok(s)
}

/// The test sshd, or `None` (the test is skipped and says why; under
/// `CI=true`, where `.ci/run` installs openssh-server, it fails instead).
fn sshd_or_skip() -> Option<Sshd> {
    match start_sshd() {
        Ok(s) => Some(s),
        Err(why) => {
            harness::skip("sshd tests", &format!("cannot start a test sshd: {why}"));
            None
        }
    }
}

/// A hosts file with 2 ssh workers on 127.0.0.1 whose binary is a symlink in a
/// unique directory (so `pgrep -f` finds exactly this test's workers).
fn hosts_file(sshd: &Sshd, tag: &str) -> (PathBuf, String) {
    let bin_dir = sshd.dir.path().join(format!("bin-{tag}"));
    std::fs::create_dir_all(&bin_dir).unwrap();
    let link = bin_dir.join("texsyn-worker");
    std::os::unix::fs::symlink(harness::binary("texsyn-worker"), &link).unwrap();
    let entry = format!(
        "[[worker]]\naddress = \"127.0.0.1\"\nssh = \"{}@127.0.0.1\"\nbinary = \"{}\"\nthreads = 1\nssh_options = [\"-F\", \"{}\"]\n\n",
        sshd.user,
        link.display(),
        sshd.config.display()
    );
    let hosts = sshd.dir.path().join(format!("hosts-{tag}.toml"));
    std::fs::write(&hosts, entry.repeat(2)).unwrap();
    // Anchored: the worker processes themselves, not the ssh clients naming them.
    (hosts, format!("^{}/texsyn-worker serve", bin_dir.display()))
}

#[test]
fn two_workers_launched_over_ssh_match_the_local_engine_and_are_gone_afterwards() {
    let Some(sshd) = sshd_or_skip() else { return };
    let (hosts, marker) = hosts_file(&sshd, "inproc");
    let (running, launch) = read_hosts_file_launch(&hosts, None, true).unwrap();
    assert!(running.is_empty());
    assert_eq!(launch.len(), 2);
    let reference = run(Strategy::Local, None);
    let addresses;
    {
        let ssh = SshWorkers::launch(&launch).unwrap();
        assert!(ssh.skipped.is_empty(), "{:?}", ssh.skipped);
        let specs: Vec<WorkerSpec> = ssh.specs();
        assert_eq!(specs.len(), 2);
        addresses = specs.iter().map(|s| s.address.clone()).collect::<Vec<_>>();
        assert_eq!(pgrep(&marker).len(), 2, "2 worker processes run");
        let options = ClusterOptions {
            workers: specs,
            require_cluster: true,
            deadline_floor: Duration::from_secs(5),
            call_timeout: Duration::from_secs(10),
            connect_timeout: Duration::from_secs(5),
            ..ClusterOptions::default()
        };
        let cluster = ClusterSearch::connect(options, Engine::default()).unwrap();
        let out = run(Strategy::Cluster, Some(cluster));
        assert!(out.image.rgb == reference.image.rgb, "image differs");
        assert!(out.copy_map == reference.copy_map, "copy map differs");
        let stats = &out.report.search_stats["cluster"]["workers"];
        for w in stats.as_array().unwrap() {
            assert!(w["queries"].as_u64().unwrap() > 0, "{w:#}");
        }
    }
    let left = wait_gone(&marker, Duration::from_secs(8));
    assert!(left.is_empty(), "workers left after the run: {left:?}");
    for a in addresses {
        let addr: std::net::SocketAddr = a.parse().unwrap();
        assert!(std::net::TcpStream::connect_timeout(&addr, Duration::from_secs(1)).is_err());
    }

    // An unreachable host is skipped with a reason.
    let bad = vec![LaunchSpec {
        ssh: format!("{}@127.0.0.1", sshd.user),
        binary: "/nonexistent/texsyn-worker".into(),
        ..launch[0].clone()
    }];
    let s = SshWorkers::launch(&bad).unwrap();
    assert!(s.workers.is_empty());
    assert_eq!(s.skipped.len(), 1);
}

#[test]
fn master_killed_mid_run_leaves_no_worker_behind() {
    let Some(sshd) = sshd_or_skip() else { return };
    let (hosts, marker) = hosts_file(&sshd, "killed");
    let out = sshd.dir.path().join("out.png");
    let mut master = Command::new(harness::binary("texsyn"))
        .arg("synth")
        .arg(texture_path("brick_color_96.png"))
        .args(["--size", "1024x1024", "--levels", "3", "--seed", "3", "-q"])
        .args(["--search", "cluster,cluster,cluster", "--require-cluster"])
        .arg("--hosts")
        .arg(&hosts)
        .arg("--launch")
        .arg("-o")
        .arg(&out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if pgrep(&marker).len() == 2 {
            break;
        }
        if let Some(st) = master.try_wait().unwrap() {
            let mut e = String::new();
            let _ = std::io::Read::read_to_string(&mut master.stderr.take().unwrap(), &mut e);
            panic!("the master ended ({st}) before its workers were seen: {e}");
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "workers not launched within 30 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // Let the run start using them, then kill the master hard.
    std::thread::sleep(Duration::from_millis(300));
    let finished = master.try_wait().unwrap().is_some();
    assert!(
        !finished,
        "the master finished before it could be killed mid-run"
    );
    harness::sigkill(master.id());
    let _ = master.wait();
    let left = wait_gone(&marker, Duration::from_secs(8));
    assert!(
        left.is_empty(),
        "workers left 8 s after the master was killed (finished before: {finished}): {left:?}"
    );
}

#[test]
fn cluster_status_prints_a_table_of_the_workers() {
    let token = harness::Token::new();
    let w = harness::Worker::with_token(9, &token, 1);
    let dead = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let out = Command::new(harness::binary("texsyn"))
        .args(["cluster", "status", "--workers"])
        .arg(format!("{},{dead}", w.address))
        .arg("--token-file")
        .arg(&token.path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.starts_with("ADDRESS"), "{text}");
    let row = text
        .lines()
        .find(|l| l.starts_with(&w.address.to_string()))
        .unwrap();
    assert!(
        row.contains(env!("CARGO_PKG_VERSION")) && row.contains("ok"),
        "{row}"
    );
    let bad = text
        .lines()
        .find(|l| l.starts_with(&dead.to_string()))
        .unwrap();
    assert!(bad.contains("error"), "{bad}");
    // A wrong token: nobody answers, the command fails.
    let wrong = token.dir.path().join("wrong");
    std::fs::write(&wrong, "nottheright").unwrap();
    let out = Command::new(harness::binary("texsyn"))
        .args(["cluster", "status", "--workers"])
        .arg(w.address.to_string())
        .arg("--token-file")
        .arg(&wrong)
        .output()
        .unwrap();
    assert!(!out.status.success());
}

/// `--launch` with TLS: the hosts entries give the workers' certificate, key
/// and client CA (paths on the host); the master's `--tls-*` flags apply to
/// them. The output is bit-identical to a local run; without a client
/// certificate the launched workers refuse the master; `--tls-ca` with an
/// entry that would launch a plaintext worker is refused up front.
#[test]
fn workers_launched_over_ssh_with_mutual_tls_match_a_local_run() {
    let Some(sshd) = sshd_or_skip() else { return };
    let pki_dir = tempfile::tempdir().unwrap();
    let Some(pki) = texsyn_integration::test_pki(pki_dir.path()) else {
        return;
    };
    let (plain_hosts, marker) = hosts_file(&sshd, "tls");
    let entries = std::fs::read_to_string(&plain_hosts).unwrap().replace(
        "threads = 1\n",
        &format!(
            "threads = 1\ntls_cert = \"{}\"\ntls_key = \"{}\"\ntls_client_ca = \"{}\"\n",
            pki.server_cert.display(),
            pki.server_key.display(),
            pki.client_ca.display()
        ),
    );
    let hosts = sshd.dir.path().join("hosts-tls-on.toml");
    std::fs::write(&hosts, entries).unwrap();
    let out_dir = tempfile::tempdir().unwrap();
    let synth = |out: &str, search: &str| {
        let mut c = Command::new(harness::binary("texsyn"));
        c.arg("synth")
            .arg(texture_path("brick_color_96.png"))
            .args(["--size", "96x96", "--levels", "3", "--seed", "3", "-q"])
            .args(["--search", search, "-o"])
            .arg(out_dir.path().join(out));
        c
    };
    let local = synth("local.png", "local,local,local").output().unwrap();
    assert!(local.status.success(), "{local:?}");
    let tls_ca = ["--tls-ca", pki.ca.to_str().unwrap()];
    let client = [
        "--tls-client-cert",
        pki.client_cert.to_str().unwrap(),
        "--tls-client-key",
        pki.client_key.to_str().unwrap(),
    ];
    let o = synth("tls.png", "cluster,cluster,cluster")
        .arg("--hosts")
        .arg(&hosts)
        .args(["--launch", "--require-cluster"])
        .args(tls_ca)
        .args(client)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        std::fs::read(out_dir.path().join("local.png")).unwrap()
            == std::fs::read(out_dir.path().join("tls.png")).unwrap(),
        "output of the TLS workers launched over ssh differs from the local run"
    );
    // Without the client certificate the launched workers refuse the master.
    let o = synth("refused.png", "cluster,cluster,cluster")
        .arg("--hosts")
        .arg(&hosts)
        .args(["--launch", "--require-cluster"])
        .args(tls_ca)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("--tls-client-cert"), "{e}");
    // --tls-ca with entries that would launch plaintext workers.
    let o = synth("plain.png", "cluster,cluster,cluster")
        .arg("--hosts")
        .arg(&plain_hosts)
        .args(["--launch", "--require-cluster"])
        .args(tls_ca)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("tls_cert") && e.contains("hosts file"), "{e}");
    let left = wait_gone(&marker, Duration::from_secs(8));
    assert!(left.is_empty(), "workers left after the runs: {left:?}");
}
