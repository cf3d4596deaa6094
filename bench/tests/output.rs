//! The bench's reports on standard output: piped into a reader that stops
//! early (`| head`), the bench ends as Unix tools do, by the pipe's signal
//! or quietly, and never panics.

use std::path::PathBuf;
use std::process::{Command, Stdio};

#[test]
fn a_closed_pipe_ends_the_report_without_a_panic() {
    let labels =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/textures/structure_labels.txt");
    let mut child = Command::new(env!("CARGO_BIN_EXE_texsyn-bench"))
        .args(["match", "--no-recovery", "--arrangement-only", "--labels"])
        .arg(&labels)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before the first line is written.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        assert!(
            out.status.success() || out.status.signal() == Some(libc::SIGPIPE),
            "{:?}: {stderr}",
            out.status
        );
    }
}
