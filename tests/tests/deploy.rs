//! The deployment files parse, and every command line in them names only flags
//! that `texsyn` / `texsyn-worker` really accept, so they cannot rot.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `target/<profile>/NAME`, next to this test's `deps/` directory.
fn binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().and_then(Path::parent).unwrap();
    let p = dir.join(name);
    assert!(
        p.exists(),
        "{} is not built; run `cargo test --workspace --release`",
        p.display()
    );
    p
}

/// Runs the command's own parser on its arguments (with `--help` appended, so
/// nothing is executed): unknown flags, bad values or subcommands fail.
fn check_command(argv: &[String], origin: &str) {
    let prog = Path::new(&argv[0])
        .file_name()
        .unwrap()
        .to_str()
        .unwrap()
        .to_string();
    assert!(
        prog == "texsyn" || prog == "texsyn-worker",
        "{origin}: unexpected program {prog}"
    );
    let out = Command::new(binary(&prog))
        .args(&argv[1..])
        .arg("--help")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{origin}: `{}` is rejected by {prog}: {}",
        argv.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn strings(v: &serde_yaml::Value) -> Vec<String> {
    match v {
        serde_yaml::Value::Sequence(s) => s
            .iter()
            .map(|x| {
                x.as_str()
                    .map(str::to_string)
                    .unwrap_or_else(|| serde_yaml::to_string(x).unwrap().trim().to_string())
            })
            .collect(),
        serde_yaml::Value::String(s) => s.split_whitespace().map(str::to_string).collect(),
        _ => Vec::new(),
    }
}

#[test]
fn the_argument_check_really_rejects_bad_flags() {
    let bad = ["texsyn-worker", "serve", "--no-such-flag", "1"].map(String::from);
    let out = Command::new(binary("texsyn-worker"))
        .args(&bad[1..])
        .arg("--help")
        .output()
        .unwrap();
    assert!(
        !out.status.success(),
        "an unknown flag must fail even with --help after it"
    );
    let out = Command::new(binary("texsyn"))
        .args(["synth", "x.png", "--method", "nope", "--help"])
        .output()
        .unwrap();
    assert!(
        !out.status.success(),
        "a bad value must fail even with --help after it"
    );
}

#[test]
fn compose_file_parses_and_its_commands_are_valid() {
    let text = std::fs::read_to_string(root().join("deploy/docker/compose.yaml")).unwrap();
    let doc: serde_yaml::Value = serde_yaml::from_str(&text).expect("compose.yaml is valid YAML");
    let services = doc["services"].as_mapping().expect("services");
    assert!(services.len() >= 4, "master + 3 workers");
    let mut checked = 0;
    for (name, svc) in services {
        let name = name.as_str().unwrap();
        // YAML merge keys (<<: *worker) are resolved by compose; follow them here.
        let svc = if svc["command"].is_null() {
            &doc["x-worker"]
        } else {
            svc
        };
        let cmd = strings(&svc["command"]);
        assert!(!cmd.is_empty(), "service {name} has no command");
        check_command(&cmd, &format!("compose service {name}"));
        checked += 1;
        let hc = strings(&svc["healthcheck"]["test"]);
        if let Some(pos) = hc.iter().position(|a| a.starts_with("texsyn")) {
            check_command(&hc[pos..], &format!("compose healthcheck of {name}"));
        }
    }
    assert!(checked >= 4);
    assert!(services.contains_key("master"));
}

#[test]
fn kubernetes_manifests_parse_and_their_commands_are_valid() {
    let text = std::fs::read_to_string(root().join("deploy/k8s/texsyn.yaml")).unwrap();
    let mut kinds = Vec::new();
    for doc in serde_yaml::Deserializer::from_str(&text) {
        let v = serde_yaml::Value::deserialize(doc).expect("valid YAML document");
        let kind = v["kind"].as_str().expect("kind").to_string();
        assert!(
            v["apiVersion"].as_str().is_some(),
            "{kind} has an apiVersion"
        );
        assert!(
            v["metadata"]["name"].as_str().is_some(),
            "{kind} has a name"
        );
        let pod = &v["spec"]["template"]["spec"];
        if let Some(containers) = pod["containers"].as_sequence() {
            for c in containers {
                let mut argv = strings(&c["command"]);
                argv.extend(strings(&c["args"]));
                check_command(&argv, &format!("{kind} container"));
                for probe in ["readinessProbe", "livenessProbe"] {
                    let p = strings(&c[probe]["exec"]["command"]);
                    if !p.is_empty() {
                        check_command(&p, &format!("{kind} {probe}"));
                    }
                }
            }
        }
        kinds.push(kind);
    }
    for k in ["Service", "StatefulSet", "Job"] {
        assert!(kinds.iter().any(|x| x == k), "manifests lack a {k}");
    }
}

use serde::Deserialize;

#[test]
fn systemd_unit_parses_and_its_command_is_valid() {
    let text =
        std::fs::read_to_string(root().join("deploy/systemd/texsyn-worker.service")).unwrap();
    let mut section = String::new();
    let mut exec = None;
    let mut sections = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if line.starts_with('[') {
            assert!(line.ends_with(']'), "line {}: bad section header", i + 1);
            section = line[1..line.len() - 1].to_string();
            sections.push(section.clone());
            continue;
        }
        let (key, value) = line
            .split_once('=')
            .unwrap_or_else(|| panic!("line {}: not key=value: {line}", i + 1));
        assert!(!section.is_empty(), "line {}: key outside a section", i + 1);
        if section == "Service" && key.trim() == "ExecStart" {
            exec = Some(value.trim().to_string());
        }
    }
    assert_eq!(sections, ["Unit", "Service", "Install"]);
    let exec = exec.expect("ExecStart");
    let argv: Vec<String> = exec
        .split_whitespace()
        .map(|a| {
            a.replace(
                "${CREDENTIALS_DIRECTORY}",
                "/run/credentials/texsyn-worker.service",
            )
        })
        .collect();
    check_command(&argv, "systemd ExecStart");
    assert!(
        text.contains("LoadCredential=token:"),
        "the token comes from a credentials file"
    );
}

#[test]
fn dockerfile_commands_are_valid() {
    let text = std::fs::read_to_string(root().join("deploy/docker/Dockerfile")).unwrap();
    assert!(text.matches("FROM ").count() >= 2, "multi-stage build");
    for line in text
        .lines()
        .filter(|l| l.starts_with("CMD") || l.starts_with("HEALTHCHECK"))
    {
        let json = &line[line.find('[').unwrap()..=line.rfind(']').unwrap()];
        let argv: Vec<String> = serde_json::from_str(json).unwrap();
        check_command(&argv, line);
    }
}
