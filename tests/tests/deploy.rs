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
        "{} is not built; run `cargo test --workspace --profile ci`",
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

// ---------------------------------------------------------------------------
// Hardening of the deploy files: no unauthenticated public worker, a memory
// cap inside the container's limit, non-root containers that can read their
// secret, and nothing secret or large in the Docker build context.

/// The worker's user and group in every container.
const UID: u64 = 10001;

fn flag<'a>(argv: &'a [String], name: &str) -> Option<&'a str> {
    argv.iter()
        .position(|a| a == name)
        .and_then(|i| argv.get(i + 1))
        .map(String::as_str)
}

/// A `texsyn-worker serve` command line: a non-loopback listener has a token
/// (and no opt-out), and `--max-memory` fits `limit` bytes with room for the
/// process itself: between half and four fifths of it.
fn check_worker_serve(argv: &[String], limit: u64, origin: &str) {
    assert_eq!(argv.get(1).map(String::as_str), Some("serve"), "{origin}");
    let listen: std::net::SocketAddr = flag(argv, "--listen")
        .unwrap_or("127.0.0.1:7878")
        .parse()
        .unwrap_or_else(|e| panic!("{origin}: --listen: {e}"));
    if !listen.ip().is_loopback() {
        assert!(
            flag(argv, "--token-file").is_some() || argv.iter().any(|a| a == "--token-stdin"),
            "{origin}: a worker listening on {listen} must require a token"
        );
        assert!(
            !argv.iter().any(|a| a == "--insecure-no-auth"),
            "{origin}: a deployed worker must not opt out of authentication"
        );
    }
    let mm = flag(argv, "--max-memory")
        .unwrap_or_else(|| panic!("{origin}: no --max-memory (the default ignores the limit)"));
    let mm = texsyn_worker::cli::parse_bytes(mm).unwrap();
    assert!(
        mm * 2 >= limit && mm * 5 <= limit * 4,
        "{origin}: --max-memory {mm} B does not fit a {limit} B limit (want 1/2 to 4/5 of it)"
    );
}

/// A memory size as Kubernetes (`Ki`/`Mi`/`Gi` binary, `K`/`M`/`G` decimal),
/// Docker Compose (`k`/`m`/`g` binary) or systemd (`K`/`M`/`G` binary) write it.
fn size(s: &str, upper_is_decimal: bool) -> u64 {
    let s = s.trim();
    let split = s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    let (n, unit) = s.split_at(split);
    let n: u64 = n.parse().unwrap_or_else(|_| panic!("bad size {s}"));
    let k: u64 =
        if upper_is_decimal && unit.len() == 1 && unit.chars().all(|c| c.is_ascii_uppercase()) {
            1000
        } else {
            1024
        };
    let pow = match unit.trim_end_matches(['i', 'b', 'B']) {
        "" => 0,
        "k" | "K" => 1,
        "m" | "M" => 2,
        "g" | "G" => 3,
        _ => panic!("bad size unit in {s}"),
    };
    n * k.pow(pow)
}

#[test]
fn size_parser_reads_each_convention() {
    assert_eq!(size("2g", false), 2 << 30);
    assert_eq!(size("512m", false), 512 << 20);
    assert_eq!(size("4Gi", true), 4 << 30);
    assert_eq!(size("4G", true), 4_000_000_000);
    assert_eq!(size("4G", false), 4 << 30);
    assert_eq!(size("1536", false), 1536);
}

fn compose() -> serde_yaml::Value {
    let text = std::fs::read_to_string(root().join("deploy/docker/compose.yaml")).unwrap();
    let mut doc: serde_yaml::Value = serde_yaml::from_str(&text).unwrap();
    doc.apply_merge().expect("merge keys");
    doc
}

#[test]
fn compose_services_are_non_root_read_only_capless_and_limited() {
    let doc = compose();
    let services = doc["services"].as_mapping().unwrap();
    let mut workers = 0;
    for (name, svc) in services {
        let name = name.as_str().unwrap();
        let user = svc["user"]
            .as_str()
            .unwrap_or_else(|| panic!("{name}: no user"));
        assert_eq!(user, format!("{UID}:{UID}"), "{name}: user");
        assert_eq!(svc["read_only"].as_bool(), Some(true), "{name}: read_only");
        assert!(
            strings(&svc["cap_drop"]).iter().any(|c| c == "ALL"),
            "{name}: cap_drop ALL"
        );
        assert!(
            strings(&svc["security_opt"])
                .iter()
                .any(|o| o == "no-new-privileges:true"),
            "{name}: no-new-privileges"
        );
        // Service-level limits: docker-compose 1.29 ignores deploy.resources.
        assert!(
            svc.get("deploy").is_none(),
            "{name}: deploy.resources is not applied by docker-compose 1.29"
        );
        let memory = svc["mem_limit"]
            .as_str()
            .unwrap_or_else(|| panic!("{name}: no mem_limit"));
        let memory = size(memory, false);
        assert!(svc["cpus"].as_f64().is_some(), "{name}: no cpu limit");
        assert!(
            svc["pids_limit"].as_u64().is_some(),
            "{name}: no pids limit"
        );
        let cmd = strings(&svc["command"]);
        if cmd[0] == "texsyn-worker" {
            check_worker_serve(&cmd, memory, &format!("compose service {name}"));
            assert!(
                strings(&svc["secrets"]).iter().any(|s| s == "texsyn_token"),
                "{name}: the token secret"
            );
            workers += 1;
        }
    }
    assert_eq!(workers, 3);
}

#[test]
fn the_compose_check_fails_on_an_unhardened_service() {
    let mut doc = compose();
    let w = &mut doc["services"]["worker1"];
    w.as_mapping_mut().unwrap().remove("user");
    assert!(w["user"].is_null(), "removing the user is seen");
    let cmd = vec![
        "texsyn-worker".to_string(),
        "serve".into(),
        "--listen".into(),
        "0.0.0.0:7878".into(),
        "--max-memory".into(),
        "1536M".into(),
    ];
    let r = std::panic::catch_unwind(|| check_worker_serve(&cmd, 2 << 30, "no token"));
    assert!(r.is_err(), "a public worker without a token is refused");
    let mut cmd = cmd;
    cmd.extend(["--token-file".into(), "/t".into()]);
    check_worker_serve(&cmd, 2 << 30, "token");
    let r = std::panic::catch_unwind(|| check_worker_serve(&cmd, 1 << 30, "too big"));
    assert!(r.is_err(), "--max-memory above 4/5 of the limit is refused");
    cmd.truncate(4);
    let r = std::panic::catch_unwind(|| check_worker_serve(&cmd, 2 << 30, "no cap"));
    assert!(r.is_err(), "no --max-memory is refused");
}

fn k8s_docs() -> Vec<serde_yaml::Value> {
    let text = std::fs::read_to_string(root().join("deploy/k8s/texsyn.yaml")).unwrap();
    serde_yaml::Deserializer::from_str(&text)
        .map(|d| serde_yaml::Value::deserialize(d).unwrap())
        .collect()
}

/// A secret volume's `defaultMode`. Kubernetes reads the manifest as YAML 1.1,
/// where `0440` is octal; serde_yaml (YAML 1.2) reads the same literal as the
/// string "0440", so its digits are read here in base 8 (a decimal 288 is
/// rejected: write modes as octal literals).
fn octal_mode(v: &serde_yaml::Value, origin: &str) -> u32 {
    let text = match v {
        serde_yaml::Value::String(s) => s.clone(),
        serde_yaml::Value::Number(n) => n.to_string(),
        _ => panic!("{origin}: no defaultMode"),
    };
    assert!(
        text.starts_with('0') && text.len() > 1,
        "{origin}: defaultMode {text} is not an octal literal like 0440"
    );
    u32::from_str_radix(&text, 8)
        .unwrap_or_else(|_| panic!("{origin}: defaultMode {text} is not an octal literal"))
}

#[test]
fn kubernetes_pods_are_hardened_limited_and_can_read_their_secret() {
    let mut pods = 0;
    for v in k8s_docs() {
        let kind = v["kind"].as_str().unwrap().to_string();
        let pod = &v["spec"]["template"]["spec"];
        let Some(containers) = pod["containers"].as_sequence() else {
            continue;
        };
        pods += 1;
        let psc = &pod["securityContext"];
        assert_eq!(
            psc["runAsNonRoot"].as_bool(),
            Some(true),
            "{kind}: runAsNonRoot"
        );
        assert_eq!(psc["runAsUser"].as_u64(), Some(UID), "{kind}: runAsUser");
        assert_eq!(psc["runAsGroup"].as_u64(), Some(UID), "{kind}: runAsGroup");
        assert_eq!(psc["fsGroup"].as_u64(), Some(UID), "{kind}: fsGroup");
        assert_eq!(
            psc["seccompProfile"]["type"].as_str(),
            Some("RuntimeDefault"),
            "{kind}: pod seccompProfile"
        );
        // Secret files are owned by root and the fsGroup: the container user
        // (not root) reads them through the group bit; nobody else may.
        let mut secrets = 0;
        for vol in pod["volumes"].as_sequence().unwrap() {
            if vol["secret"].is_null() {
                continue;
            }
            secrets += 1;
            let mode = octal_mode(&vol["secret"]["defaultMode"], &kind);
            assert!(
                mode & 0o040 != 0,
                "{kind}: secret mode {mode:o} is not readable by the fsGroup"
            );
            assert_eq!(
                mode & 0o007,
                0,
                "{kind}: secret mode {mode:o} is world-readable"
            );
            assert_eq!(mode & 0o222, 0, "{kind}: secret mode {mode:o} is writable");
        }
        assert!(secrets > 0, "{kind}: the token secret");
        for c in containers {
            let name = c["name"].as_str().unwrap();
            let origin = format!("{kind} container {name}");
            let sc = &c["securityContext"];
            assert_eq!(
                sc["runAsNonRoot"].as_bool(),
                Some(true),
                "{origin}: runAsNonRoot"
            );
            assert_eq!(sc["runAsUser"].as_u64(), Some(UID), "{origin}: runAsUser");
            assert_eq!(
                sc["allowPrivilegeEscalation"].as_bool(),
                Some(false),
                "{origin}: allowPrivilegeEscalation"
            );
            assert_eq!(
                sc["readOnlyRootFilesystem"].as_bool(),
                Some(true),
                "{origin}: readOnlyRootFilesystem"
            );
            assert!(
                strings(&sc["capabilities"]["drop"])
                    .iter()
                    .any(|x| x == "ALL"),
                "{origin}: capabilities drop ALL"
            );
            assert_eq!(
                sc["seccompProfile"]["type"].as_str(),
                Some("RuntimeDefault"),
                "{origin}: seccompProfile"
            );
            let res = &c["resources"];
            for part in ["requests", "limits"] {
                for what in ["cpu", "memory"] {
                    assert!(
                        !res[part][what].is_null(),
                        "{origin}: resources.{part}.{what}"
                    );
                }
            }
            let limit = size(res["limits"]["memory"].as_str().unwrap(), true);
            let request = size(res["requests"]["memory"].as_str().unwrap(), true);
            assert!(request <= limit, "{origin}: request above limit");
            let argv = strings(&c["command"]);
            if argv[0] == "texsyn-worker" {
                check_worker_serve(&argv, limit, &origin);
            }
        }
    }
    assert_eq!(pods, 2, "the worker StatefulSet and the master Job");
}

#[test]
fn octal_modes_are_read_as_kubernetes_reads_them() {
    let v: serde_yaml::Value = serde_yaml::from_str("m: 0440").unwrap();
    assert_eq!(octal_mode(&v["m"], "test"), 0o440);
    let v: serde_yaml::Value = serde_yaml::from_str("m: 0400").unwrap();
    assert_eq!(octal_mode(&v["m"], "test") & 0o040, 0, "0400 is owner-only");
}

#[test]
fn systemd_worker_has_a_token_and_a_memory_cap_inside_its_limit() {
    let text =
        std::fs::read_to_string(root().join("deploy/systemd/texsyn-worker.service")).unwrap();
    let value = |key: &str| {
        text.lines()
            .find_map(|l| l.trim().strip_prefix(key)?.strip_prefix('='))
            .map(str::trim)
            .unwrap_or_else(|| panic!("no {key}="))
    };
    let limit = size(value("MemoryMax"), false);
    let argv: Vec<String> = value("ExecStart")
        .split_whitespace()
        .map(str::to_string)
        .collect();
    assert!(argv[0].ends_with("/texsyn-worker"));
    check_worker_serve(&argv, limit, "systemd ExecStart");
    assert_eq!(value("NoNewPrivileges"), "yes");
    assert_eq!(value("DynamicUser"), "yes");
}

/// `Dockerfile` lines that start with `word`, continuation lines joined.
fn dockerfile_lines(word: &str) -> Vec<String> {
    let text = std::fs::read_to_string(root().join("deploy/docker/Dockerfile")).unwrap();
    let mut lines = Vec::new();
    let mut cur = String::new();
    for l in text.lines() {
        if cur.is_empty() && l.trim_start().starts_with('#') {
            continue;
        }
        match l.strip_suffix('\\') {
            Some(head) => cur.push_str(head),
            None => {
                cur.push_str(l);
                if cur.starts_with(word) {
                    lines.push(cur.clone());
                }
                cur.clear();
            }
        }
    }
    lines
}

fn json_argv(line: &str) -> Vec<String> {
    serde_json::from_str(&line[line.find('[').unwrap()..=line.rfind(']').unwrap()]).unwrap()
}

#[test]
fn dockerfile_default_is_an_authenticated_non_root_worker_with_a_memory_cap() {
    let text = std::fs::read_to_string(root().join("deploy/docker/Dockerfile")).unwrap();
    let users = dockerfile_lines("USER ");
    assert_eq!(
        users.last().map(String::as_str),
        Some(format!("USER {UID}:{UID}").as_str()),
        "the image runs as a numeric non-root user (runAsNonRoot can check it)"
    );
    let cmd = dockerfile_lines("CMD ");
    assert_eq!(cmd.len(), 1);
    let argv = json_argv(&cmd[0]);
    assert_eq!(
        flag(&argv, "--token-file"),
        Some("/run/secrets/texsyn_token"),
        "the default worker reads the token from the Docker secret"
    );
    // The limit the image is documented for: `docker run --memory 2g`.
    let documented = text
        .split("--memory ")
        .nth(1)
        .and_then(|t| t.split(|c: char| c.is_whitespace() || c == '`').next())
        .expect("the Dockerfile names the container memory limit its --max-memory is for");
    check_worker_serve(&argv, size(documented, false), "Dockerfile CMD");
    let hc = dockerfile_lines("HEALTHCHECK ");
    assert_eq!(
        flag(&json_argv(&hc[0]), "--token-file"),
        Some("/run/secrets/texsyn_token"),
        "the health check authenticates too"
    );
    let readme = std::fs::read_to_string(root().join("deploy/README.md")).unwrap();
    assert!(
        readme.contains("/run/secrets/texsyn_token"),
        "deploy/README.md says where the image's worker reads its token"
    );
}

// .dockerignore, matched the way Docker matches it: patterns relative to the
// context root, `*` and `?` within a path component, `**` any number of
// components, a pattern matching a directory excludes what is under it, `!`
// re-includes, and the last matching pattern wins.

fn dockerignore() -> Vec<(bool, Vec<String>)> {
    let path = root().join(".dockerignore");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (the build context is the repository root)",
            path.display()
        )
    });
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| {
            let (neg, p) = match l.strip_prefix('!') {
                Some(p) => (true, p),
                None => (false, l),
            };
            let comps = p
                .trim_start_matches('/')
                .trim_end_matches('/')
                .split('/')
                .filter(|c| !c.is_empty() && *c != ".")
                .map(str::to_string)
                .collect();
            (neg, comps)
        })
        .collect()
}

fn glob(p: &[u8], s: &[u8]) -> bool {
    match (p.first(), s.first()) {
        (None, None) => true,
        (Some(b'*'), _) => glob(&p[1..], s) || (!s.is_empty() && glob(p, &s[1..])),
        (Some(b'?'), Some(_)) => glob(&p[1..], &s[1..]),
        (Some(a), Some(b)) if a == b => glob(&p[1..], &s[1..]),
        _ => false,
    }
}

fn glob_path(p: &[String], s: &[&str]) -> bool {
    match p.first() {
        None => s.is_empty(),
        Some(c) if c == "**" => (0..=s.len()).any(|k| glob_path(&p[1..], &s[k..])),
        Some(c) => {
            !s.is_empty() && glob(c.as_bytes(), s[0].as_bytes()) && glob_path(&p[1..], &s[1..])
        }
    }
}

fn ignored(rules: &[(bool, Vec<String>)], path: &str) -> bool {
    let comps: Vec<&str> = path.split('/').collect();
    let mut out = false;
    for (neg, p) in rules {
        if (1..=comps.len()).any(|n| glob_path(p, &comps[..n])) {
            out = !neg;
        }
    }
    out
}

#[test]
fn dockerignore_matcher_follows_docker_rules() {
    let rules = |s: &[&str]| -> Vec<(bool, Vec<String>)> {
        s.iter()
            .map(|l| {
                let (neg, p) = l.strip_prefix('!').map_or((false, *l), |p| (true, p));
                (neg, p.split('/').map(str::to_string).collect())
            })
            .collect()
    };
    let r = rules(&["target", "**/*.token", "!keep.token"]);
    assert!(ignored(&r, "target/release/texsyn"));
    assert!(!ignored(&r, "master/target2"));
    assert!(
        !ignored(&r, "master/target/x"),
        "`target` is the root one only"
    );
    assert!(ignored(&r, "a/b/c.token") && ignored(&r, "c.token"));
    assert!(!ignored(&r, "keep.token"));
    assert!(!ignored(&r, "Cargo.toml"));
}

/// Every file of the workspace members below `dir` (build output skipped).
fn sources(dir: &Path, rel: &str, out: &mut Vec<String>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let name = e.file_name().into_string().unwrap();
        let rel = if rel.is_empty() {
            name.clone()
        } else {
            format!("{rel}/{name}")
        };
        let ft = e.file_type().unwrap();
        if ft.is_dir() && name != "target" && name != ".git" {
            sources(&e.path(), &rel, out);
        } else if ft.is_file() {
            out.push(rel);
        }
    }
}

#[test]
fn dockerignore_keeps_secrets_and_build_output_out_and_the_build_inputs_in() {
    let rules = dockerignore();
    for p in [
        "target/release/texsyn",
        "worker/target/debug/x",
        ".git/HEAD",
        "deploy/docker/token",
        "token",
        "deploy/prod.token",
        "secrets/token.txt",
        "deploy/docker/out/brick_cluster.png",
        "out/run.json",
        "master/x.png.tmp",
        "worker/tls/key.pem",
    ] {
        assert!(
            ignored(&rules, p),
            ".dockerignore lets {p} into the build context"
        );
    }
    // What the build needs stays: the workspace manifests, every member's
    // sources and the bundled textures.
    let mut needed = vec![
        "Cargo.toml".to_string(),
        "Cargo.lock".into(),
        "deploy/docker/Dockerfile".into(),
    ];
    for member in [
        "proto",
        "worker",
        "master",
        "bench",
        "tests",
        "assets/textures",
    ] {
        sources(&root().join(member), member, &mut needed);
    }
    assert!(needed.len() > 50, "{needed:?}");
    assert!(needed.iter().any(|p| p == "worker/engine/Cargo.toml"));
    for p in &needed {
        assert!(
            !ignored(&rules, p),
            ".dockerignore drops {p}, which the image build needs"
        );
    }
}

// Kubernetes' own API types (k8s-openapi): every field of every manifest must
// be one the API knows, at the place it is written.

/// `v` with each `defaultMode`/`mode` octal literal as the number
/// Kubernetes reads (YAML 1.1; see [`octal_mode`]).
fn as_kubernetes_reads(v: &mut serde_yaml::Value) {
    match v {
        serde_yaml::Value::Mapping(m) => {
            for (k, val) in m.iter_mut() {
                if matches!(k.as_str(), Some("defaultMode" | "mode")) {
                    if let serde_yaml::Value::String(s) = val {
                        let n = u32::from_str_radix(s, 8)
                            .unwrap_or_else(|_| panic!("mode {s} is not octal"));
                        *val = serde_yaml::Value::Number(n.into());
                    }
                }
                as_kubernetes_reads(val);
            }
        }
        serde_yaml::Value::Sequence(s) => s.iter_mut().for_each(as_kubernetes_reads),
        _ => {}
    }
}

/// Deserialises `doc` into the API type of its kind; the paths of the
/// fields that type does not have, or why it does not deserialise.
fn unknown_fields(doc: &serde_yaml::Value) -> Result<Vec<String>, String> {
    use k8s_openapi::api::{apps::v1 as apps, batch::v1 as batch, core::v1 as core};
    fn typed<T: serde::de::DeserializeOwned>(
        doc: &serde_yaml::Value,
    ) -> Result<Vec<String>, String> {
        let mut unknown = Vec::new();
        // Optional fields show as `?` segments: the API's path has none.
        serde_ignored::deserialize::<_, _, T>(doc.clone(), |path| {
            unknown.push(path.to_string().replace(".?", ""))
        })
        .map_err(|e| e.to_string())?;
        Ok(unknown)
    }
    let mut doc = doc.clone();
    as_kubernetes_reads(&mut doc);
    match (doc["apiVersion"].as_str(), doc["kind"].as_str()) {
        (Some("v1"), Some("Service")) => typed::<core::Service>(&doc),
        (Some("v1"), Some("Secret")) => typed::<core::Secret>(&doc),
        (Some("v1"), Some("ConfigMap")) => typed::<core::ConfigMap>(&doc),
        (Some("apps/v1"), Some("StatefulSet")) => typed::<apps::StatefulSet>(&doc),
        (Some("apps/v1"), Some("Deployment")) => typed::<apps::Deployment>(&doc),
        (Some("batch/v1"), Some("Job")) => typed::<batch::Job>(&doc),
        (v, k) => Err(format!("no API type for apiVersion {v:?} kind {k:?}")),
    }
}

#[test]
fn kubernetes_manifests_deserialise_into_the_api_types_with_no_unknown_field() {
    let docs = k8s_docs();
    assert!(docs.len() >= 3, "Service, StatefulSet, Job");
    for doc in &docs {
        let kind = doc["kind"].as_str().unwrap_or("?");
        let unknown = unknown_fields(doc).unwrap_or_else(|e| panic!("{kind}: {e}"));
        assert!(unknown.is_empty(), "{kind}: unknown fields {unknown:?}");
    }
}

/// The check is not vacuous: a misspelt field, a field at the wrong level, a
/// wrong type and an unknown kind are each caught.
#[test]
fn the_kubernetes_check_catches_misspelt_misplaced_and_mistyped_fields() {
    let docs = k8s_docs();
    let set = docs
        .iter()
        .find(|d| d["kind"] == "StatefulSet")
        .expect("a StatefulSet");
    let pod = |d: &mut serde_yaml::Value| -> serde_yaml::Mapping {
        d["spec"]["template"]["spec"].as_mapping().unwrap().clone()
    };

    let mut misspelt = set.clone();
    let mut spec = pod(&mut misspelt);
    let sc = spec.remove("securityContext").unwrap();
    spec.insert("securityContxt".into(), sc);
    misspelt["spec"]["template"]["spec"] = spec.into();
    let unknown = unknown_fields(&misspelt).unwrap();
    assert_eq!(
        unknown,
        vec!["spec.template.spec.securityContxt".to_string()]
    );

    let mut misplaced = set.clone();
    let mut spec = pod(&mut misplaced);
    spec.insert("replicas".into(), 3.into());
    misplaced["spec"]["template"]["spec"] = spec.into();
    assert_eq!(
        unknown_fields(&misplaced).unwrap(),
        vec!["spec.template.spec.replicas".to_string()]
    );

    let mut mistyped = set.clone();
    mistyped["spec"]["replicas"] = "three".into();
    assert!(unknown_fields(&mistyped).is_err(), "replicas: \"three\"");

    let mut unknown_kind = set.clone();
    unknown_kind["kind"] = "StatefulSett".into();
    assert!(unknown_fields(&unknown_kind).is_err());
}
