//! Worker launchers (Stahlhut §8 "launches the clients remotely", ARCHITECTURE
//! §4.2, §4.4): where the workers are ([`hosts`]: `--workers`, hosts files),
//! worker processes on this machine ([`local`]: `--local-workers N`) and over
//! ssh ([`ssh`]: `--hosts FILE --launch`). Each gives the cluster
//! [`WorkerSpec`]s to connect to and stops its workers when dropped.

pub mod hosts;
pub mod local;
pub mod ssh;

use std::io::{BufRead, BufReader};
use std::process::{ChildStdout, Command};
use std::time::Duration;

use anyhow::{Context, Result};

pub use crate::cluster::WorkerSpec;
pub use hosts::{parse_worker_list, read_hosts_file, read_hosts_file_launch, LaunchSpec};
pub use local::{find_worker_binary, LocalWorkers};
pub use ssh::SshWorkers;

/// How long a started worker gets to print its listening line.
pub const START_TIMEOUT: Duration = Duration::from_secs(20);

/// On Linux the started process gets SIGTERM when the thread that started it
/// ends, so a master killed with SIGKILL leaves no worker (or ssh session)
/// behind. (Start workers from a thread that outlives them: the main thread,
/// or a test's.)
pub fn end_with_parent(cmd: &mut Command) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: only async-signal-safe prctl(2) runs between fork and exec;
        // it reads and writes no memory of this process.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM as libc::c_ulong);
                Ok(())
            });
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = cmd;
}

/// The first line the process prints on `stdout` (its `listening on ADDR`),
/// or `None` when it prints none within [`START_TIMEOUT`]. The rest of its
/// output is drained on a thread, so it never blocks on a full pipe.
fn first_line(stdout: ChildStdout, thread: &str) -> Result<Option<String>> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name(thread.into())
        .spawn(move || {
            let mut lines = BufReader::new(stdout).lines();
            let _ = tx.send(lines.next());
            for _ in lines {}
        })
        .context("cannot start a thread")?;
    Ok(match rx.recv_timeout(START_TIMEOUT) {
        Ok(Some(Ok(line))) => Some(line),
        _ => None,
    })
}

/// The cluster of one run: what to connect to, and the workers started for
/// it (stopped when this is dropped; drop the search backend first).
#[derive(Debug)]
pub struct ClusterSetup {
    pub options: crate::cluster::ClusterOptions,
    pub local: Option<LocalWorkers>,
    /// Workers launched over ssh (`--launch`), stopped when this is dropped.
    pub ssh: Option<SshWorkers>,
}
