//! `texsyn-bench faults` end to end: a short seeded campaign over real worker
//! processes and the real master binary must come out bit-identical with
//! nothing left behind, and a master that leaves a temporary file must fail it.
//!
//! Partition faults need root and nftables. Without them the campaign runs
//! without partitions and the test says so (`SKIP partitions: ...`), except
//! with `CI=true`, where it fails: CI runs as root and installs nftables.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn bench() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_texsyn-bench"))
}

/// The campaign needs `texsyn` and `texsyn-worker` beside `texsyn-bench`;
/// `cargo test --workspace` builds them, a narrower run may not have.
fn sibling_binaries() -> PathBuf {
    let dir = bench().parent().unwrap().to_path_buf();
    if !dir.join("texsyn").is_file() || !dir.join("texsyn-worker").is_file() {
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let mut c = Command::new(cargo);
        c.args(["build", "-p", "texsyn", "-p", "texsyn-worker"]);
        // target/<dir>: the profile that built this test (debug is `dev`).
        match dir.file_name().and_then(|n| n.to_str()) {
            Some("debug") | None => {}
            Some(profile) => {
                c.args(["--profile", profile]);
            }
        }
        assert!(c.status().unwrap().success(), "cargo build of the binaries");
    }
    dir
}

/// Whether partitions can be made here: root, namespaces and `nft`.
fn partitions_possible() -> Result<(), String> {
    // SAFETY: geteuid(2) has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Err("not root".into());
    }
    match Command::new("nft").arg("--version").output() {
        Ok(o) if o.status.success() => Ok(()),
        _ => Err("nft (nftables) is not installed".into()),
    }
}

fn kinds() -> &'static str {
    const ALL: &str = "kill,stop,partition,restart,slow,lie";
    match partitions_possible() {
        Ok(()) => ALL,
        Err(reason) => {
            assert!(
                std::env::var("CI").map_or(true, |v| v != "true"),
                "partition faults cannot run under CI=true: {reason}"
            );
            let _ = writeln!(std::io::stderr(), "SKIP partitions: {reason}");
            "kill,stop,restart,slow,lie"
        }
    }
}

fn campaign(dir: &Path, kinds: &str, extra: &[&str]) -> Output {
    let json = dir.join("summary.json");
    Command::new(bench())
        .args(["faults", "--runs", "4", "--workers", "2", "--size", "192"])
        .args(["--levels", "3", "--fault-free", "1", "--seed", "11"])
        .args(["--kinds", kinds, "--out"])
        .arg(dir.join("runs"))
        .arg("--json")
        .arg(&json)
        .args(extra)
        .output()
        .expect("run texsyn-bench faults")
}

#[test]
fn a_seeded_campaign_is_bit_identical_and_leaves_nothing_behind() {
    sibling_binaries();
    let dir = tempfile::tempdir().unwrap();
    let out = campaign(dir.path(), kinds(), &[]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: Value = serde_json::from_slice(&std::fs::read(dir.path().join("summary.json")).unwrap())
        .expect("the summary is JSON");
    assert_eq!(s["runs"], 4, "{stdout}");
    assert_eq!(s["identical"], 4, "{stdout}");
    assert_eq!(s["processes_left"], 0, "{stdout}");
    assert_eq!(s["files_left"], 0, "{stdout}");
    let injected: u64 = s["injected"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert!(injected >= 1, "some fault was injected: {stdout}");
    // Every run's image is the local engine's, byte for byte.
    let truth = std::fs::read(dir.path().join("runs/local.png")).unwrap();
    for k in 0..4 {
        let run = dir.path().join(format!("runs/run{k:03}/out.png"));
        assert!(std::fs::read(&run).unwrap() == truth, "{}", run.display());
    }
    // The same seed draws the same faults.
    let again = tempfile::tempdir().unwrap();
    assert!(campaign(again.path(), kinds(), &[]).status.success());
    let s2: Value =
        serde_json::from_slice(&std::fs::read(again.path().join("summary.json")).unwrap()).unwrap();
    let plans = |s: &Value| -> Vec<Vec<(String, u64)>> {
        s["results"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                r["faults"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|f| {
                        (
                            f["kind"].as_str().unwrap().to_string(),
                            f["worker"].as_u64().unwrap(),
                        )
                    })
                    .collect()
            })
            .collect()
    };
    assert_eq!(plans(&s), plans(&s2), "same seed, same faults");
}

#[test]
fn a_temporary_file_left_behind_fails_the_campaign() {
    let bins = sibling_binaries();
    let dir = tempfile::tempdir().unwrap();
    // A master that leaves a file in its temporary directory, then runs as usual.
    let wrapper = dir.path().join("leaky-texsyn");
    std::fs::write(
        &wrapper,
        format!(
            "#!/bin/sh\ntouch \"$TMPDIR/leak-$$\"\nexec '{}' \"$@\"\n",
            bins.join("texsyn").display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&wrapper, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = campaign(
        dir.path(),
        "kill",
        &["--master-binary", wrapper.to_str().unwrap()],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the leak went unnoticed");
    assert!(
        stderr.contains("left behind"),
        "the error names what was left: {stderr}"
    );
}
