//! The fault injectors and the checks after a run: threads pinned beside busy
//! processes (`slow`), the private network namespace and its nftables cuts and
//! heals (`partition`), and the processes and files a run left behind.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use texsyn::launch::end_with_parent;

use super::seconds;

/// nftables tables of the partitions are `PREFIX<worker>`.
const NFT_PREFIX: &str = "texsyn_faults_w";
/// Busy processes beside a slowed worker.
pub(super) const HOGS: usize = 2;

pub(super) fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Pins every thread of `pid` to `cpu`, or frees it (None: every core).
pub(super) fn pin_threads(pid: u32, cpu: Option<usize>) {
    // SAFETY: cpu_set_t is plain data; CPU_SET writes within it.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    for c in 0..cores() {
        if cpu.is_none_or(|p| p == c) {
            unsafe { libc::CPU_SET(c, &mut set) };
        }
    }
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return;
    };
    for t in tasks.flatten() {
        if let Some(tid) = t
            .file_name()
            .to_str()
            .and_then(|s| s.parse::<libc::pid_t>().ok())
        {
            // SAFETY: sched_setaffinity(2) reads `set`, a valid cpu_set_t.
            unsafe {
                libc::sched_setaffinity(tid, std::mem::size_of::<libc::cpu_set_t>(), &set);
            }
        }
    }
}

/// A busy process pinned to `cpu` for at most `lasts` (`texsyn-bench hog`).
pub(super) fn spawn_hog(cpu: usize, lasts: Duration) -> Result<Child> {
    let mut c = Command::new(std::env::current_exe()?);
    c.args(["hog", "--cpu", &cpu.to_string(), "--seconds"])
        .arg(format!("{}", lasts.as_secs_f64()))
        .stdin(Stdio::null());
    end_with_parent(&mut c);
    Ok(c.spawn()?)
}

/// `texsyn-bench hog`: spins on one core for a while (the slow fault's neighbour).
#[derive(Args, Debug)]
pub struct HogArgs {
    #[arg(long)]
    pub cpu: usize,
    #[arg(long, value_parser = |s: &str| seconds(s, 0.0, 3600.0))]
    pub seconds: Duration,
}

pub fn hog(a: &HogArgs) -> Result<()> {
    pin_threads(std::process::id(), Some(a.cpu));
    let t = Instant::now();
    let mut x = 0u64;
    while t.elapsed() < a.seconds {
        for i in 0..100_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
        }
    }
    std::hint::black_box(x);
    Ok(())
}

/// Makes this thread's network namespace a fresh one with loopback up, and
/// checks that nftables works in it.
pub(super) fn enter_private_network() -> Result<()> {
    // SAFETY: unshare(2) changes only this thread's network namespace; the
    // processes it starts from now on inherit it.
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0 {
        bail!("unshare(CLONE_NEWNET): {}", std::io::Error::last_os_error());
    }
    let lo = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .output()
        .context("cannot run `ip` (iproute2)")?;
    ensure!(lo.status.success(), "`ip link set lo up` failed");
    nft(&format!("add table inet {NFT_PREFIX}probe"))?;
    nft(&format!("delete table inet {NFT_PREFIX}probe"))?;
    Ok(())
}

fn nft(script: &str) -> Result<()> {
    let mut child = Command::new("nft")
        .args(["-f", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot run `nft` (nftables)")?;
    std::io::Write::write_all(
        &mut child.stdin.take().context("nft stdin")?,
        script.as_bytes(),
    )?;
    let out = child.wait_with_output()?;
    ensure!(
        out.status.success(),
        "`nft` failed on {script:?}: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}

/// Drops every packet to and from `port` (one nftables transaction).
pub(super) fn cut(k: usize, port: u16) -> Result<()> {
    let t = format!("{NFT_PREFIX}{k}");
    nft(&format!(
        "add table inet {t}\n\
         add chain inet {t} input {{ type filter hook input priority 0; policy accept; }}\n\
         add rule inet {t} input tcp dport {port} drop\n\
         add rule inet {t} input tcp sport {port} drop\n"
    ))
}

/// Ends worker `k`'s partition (no error when there is none).
pub(super) fn heal(k: usize) -> Result<()> {
    let t = format!("{NFT_PREFIX}{k}");
    nft(&format!("add table inet {t}\ndelete table inet {t}\n"))
}

/// The processes among `pids`, and any other whose command line names the
/// campaign directory, still alive (this process excepted).
pub(super) fn leftover_processes(pids: &[u32], root: &Path) -> Vec<String> {
    let me = std::process::id();
    let root = root.to_string_lossy().into_owned();
    let mut left = Vec::new();
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return left;
    };
    for p in procs.flatten() {
        let Some(pid) = p.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if pid == me || !alive(pid) {
            continue;
        }
        let cmdline = std::fs::read(p.path().join("cmdline"))
            .map(|b| String::from_utf8_lossy(&b).replace('\0', " "))
            .unwrap_or_default();
        if pids.contains(&pid) || cmdline.contains(&root) {
            left.push(format!("{pid}: {}", cmdline.trim()));
        }
    }
    left
}

/// True while the process exists and is not a zombie.
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| {
        s.rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .is_some_and(|state| state != "Z" && state != "X")
    })
}

/// Whatever is in `tmp` (then removed, so the next run starts clean), and any
/// file in the run directory that is not the run's own output, report or log.
pub(super) fn leftover_files(tmp: &Path, dir: &Path) -> Vec<String> {
    let mut left = Vec::new();
    for e in std::fs::read_dir(tmp).into_iter().flatten().flatten() {
        left.push(e.path().display().to_string());
        let _ = std::fs::remove_dir_all(e.path()).or_else(|_| std::fs::remove_file(e.path()));
    }
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let expected = matches!(name.as_str(), "out.png" | "report.json" | "master.log")
            || (name.starts_with("worker") && name.ends_with(".log"));
        if !expected {
            left.push(e.path().display().to_string());
        }
    }
    left
}
