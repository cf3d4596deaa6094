//! The temporaries of this process — atomic-write temp files, token and log
//! directories, started worker processes — registered while they exist, so
//! that a SIGINT or SIGTERM removes them before the process exits.
//!
//! Each temporary is created and registered under one lock ([`register`]),
//! so a signal never falls between the two; once [`clean_up`] has run,
//! nothing new can be registered. The binary installs the handler with
//! [`install_signal_handlers`]: on SIGINT or SIGTERM it signals the
//! processes, removes the files and directories and exits with 130 or 143.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

/// Exit code after SIGINT (128 + 2).
pub const EXIT_SIGINT: i32 = 130;
/// Exit code after SIGTERM (128 + 15).
pub const EXIT_SIGTERM: i32 = 143;

/// One temporary of this process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Temporary {
    /// A file, removed on clean-up.
    File(PathBuf),
    /// A directory, removed with its contents on clean-up.
    Dir(PathBuf),
    /// A child process (not yet reaped), killed (SIGKILL) on clean-up.
    Kill(u32),
    /// A child process (not yet reaped) that is asked to end (SIGTERM) on
    /// clean-up, e.g. an ssh client, which then ends its remote session.
    Terminate(u32),
}

struct Registry {
    next: u64,
    live: BTreeMap<u64, Temporary>,
    /// Set by [`clean_up`]: the process is ending, nothing new is registered.
    closed: bool,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    next: 0,
    live: BTreeMap::new(),
    closed: false,
});

fn registry() -> MutexGuard<'static, Registry> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// A registered temporary; dropping it unregisters it (removing the
/// temporary is then up to its owner). Drop it before reaping a process, so
/// a reused pid is never signalled.
#[derive(Debug)]
#[must_use = "dropping the registration unregisters the temporary at once"]
pub struct Registration(u64);

impl Drop for Registration {
    fn drop(&mut self) {
        registry().live.remove(&self.0);
    }
}

/// Runs `create`, which makes a temporary, and registers it as `what(&it)`,
/// both under the registry lock; after [`clean_up`] it creates nothing and
/// returns `interrupted()`.
pub fn register<T, E>(
    create: impl FnOnce() -> Result<T, E>,
    what: impl FnOnce(&T) -> Temporary,
    interrupted: impl FnOnce() -> E,
) -> Result<(T, Registration), E> {
    let mut r = registry();
    if r.closed {
        return Err(interrupted());
    }
    let value = create()?;
    let id = r.next;
    r.next += 1;
    r.live.insert(id, what(&value));
    Ok((value, Registration(id)))
}

/// The temporaries registered now.
pub fn registered() -> Vec<Temporary> {
    registry().live.values().cloned().collect()
}

/// Removes every registered temporary — processes are signalled first, so
/// they stop writing into the directories — and refuses new ones from now
/// on. Returns how many temporaries it handled.
pub fn clean_up() -> usize {
    let mut r = registry();
    r.closed = true;
    let live = std::mem::take(&mut r.live);
    for t in live.values() {
        match t {
            Temporary::Kill(pid) => signal(*pid, true),
            Temporary::Terminate(pid) => signal(*pid, false),
            _ => {}
        }
    }
    for t in live.values() {
        let result = match t {
            Temporary::File(p) => std::fs::remove_file(p),
            Temporary::Dir(p) => std::fs::remove_dir_all(p),
            _ => Ok(()),
        };
        if let Err(e) = result {
            if e.kind() != std::io::ErrorKind::NotFound {
                tracing::warn!(temporary = ?t, error = %e, "cannot remove a temporary");
            }
        }
    }
    live.len()
}

#[cfg(target_os = "linux")]
fn signal(pid: u32, kill: bool) {
    let Ok(pid) = libc::pid_t::try_from(pid) else {
        return;
    };
    let sig = if kill { libc::SIGKILL } else { libc::SIGTERM };
    // SAFETY: kill(2) reads no memory of this process; the pid is a child
    // that has not been reaped yet (its registration is dropped before that).
    unsafe {
        libc::kill(pid, sig);
    }
}

#[cfg(not(target_os = "linux"))]
fn signal(_pid: u32, _kill: bool) {}

/// Installs the handler of SIGINT and SIGTERM (ctrl-c on other systems): on
/// either, [`clean_up`] runs, one line goes to stderr and the process exits
/// with [`EXIT_SIGINT`] or [`EXIT_SIGTERM`]. For binaries; call it once.
pub fn install_signal_handlers() -> anyhow::Result<()> {
    use anyhow::Context;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .build()
        .context("cannot start the signal handler")?;
    // The handlers are in place when this returns.
    #[cfg(unix)]
    let wait = {
        use tokio::signal::unix::{signal, SignalKind};
        let _guard = rt.enter();
        let mut int = signal(SignalKind::interrupt()).context("cannot handle SIGINT")?;
        let mut term = signal(SignalKind::terminate()).context("cannot handle SIGTERM")?;
        async move {
            tokio::select! {
                _ = int.recv() => ("SIGINT", EXIT_SIGINT),
                _ = term.recv() => ("SIGTERM", EXIT_SIGTERM),
            }
        }
    };
    #[cfg(not(unix))]
    let wait = async {
        let _ = tokio::signal::ctrl_c().await;
        ("ctrl-c", EXIT_SIGINT)
    };
    std::thread::Builder::new()
        .name("texsyn-signals".into())
        .spawn(move || {
            let (name, code) = rt.block_on(wait);
            let n = clean_up();
            tracing::info!(signal = name, temporaries = n, "interrupted");
            eprintln!("texsyn: interrupted by {name}; temporary files removed");
            std::process::exit(code);
        })
        .context("cannot start the signal handler thread")?;
    Ok(())
}
