//! The paper's two configurations (Stahlhut Table 1 and §10.2, ARCHITECTURE §6)
//! and what the benchmarks that run them share: the texture directory, the
//! options of a run and the thread pool.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use texsyn::imaging::ColorImage;
use texsyn::{Config, Mode, SynthMethod};

/// One of the paper's configurations.
pub struct Case {
    pub name: &'static str,
    pub file: &'static str,
    pub size: usize,
    pub block: usize,
    pub neighbourhood: usize,
    pub levels: usize,
}

impl Case {
    /// The configuration and mode of this case with batch size `batch`.
    pub fn run(&self, batch: usize) -> (Config, Mode) {
        let cfg = Config {
            block: self.block,
            neighbourhood: self.neighbourhood,
            levels: self.levels,
            batch,
            ..Config::default()
        };
        let mode = Mode::Synth {
            width: self.size,
            height: self.size,
            method: SynthMethod::Grow,
        };
        (cfg, mode)
    }

    /// `(a) 192x192 from brick_gray_64.png (64x64), 9x9 neighbourhood, 3x3
    /// blocks, 3 levels`: the start of this case's line in a table.
    pub fn describe(&self, sample: &ColorImage, levels: usize) -> String {
        format!(
            "({}) {}x{} from {} ({}x{}), {}x{} neighbourhood, {}x{} blocks, {} levels",
            self.name,
            self.size,
            self.size,
            self.file,
            sample.width,
            sample.height,
            self.neighbourhood,
            self.neighbourhood,
            self.block,
            self.block,
            levels
        )
    }
}

/// (a) and (b) of Stahlhut Table 1.
pub const CASES: [Case; 2] = [
    Case {
        name: "a",
        file: "brick_gray_64.png",
        size: 192,
        block: 3,
        neighbourhood: 9,
        levels: 3,
    },
    Case {
        name: "b",
        file: "gravel_gray_500.png",
        size: 1000,
        block: 5,
        neighbourhood: 11,
        levels: 4,
    },
];

/// Where the texture photos are.
#[derive(Args, Debug)]
pub struct Textures {
    /// Directory with the texture photos (default: the repository's assets/textures).
    #[arg(long)]
    pub textures: Option<PathBuf>,
}

impl Textures {
    /// `--textures`, else `assets/textures` under the current directory, else
    /// the repository's `assets/textures`; it must be a directory.
    pub fn dir(&self) -> Result<PathBuf> {
        self.resolve()
            .context("texture directory for the bench (give --textures DIR)")
    }

    fn resolve(&self) -> Result<PathBuf> {
        let dir = self.textures.clone().unwrap_or_else(|| {
            let here = PathBuf::from("assets/textures");
            if here.is_dir() {
                here
            } else {
                let bench = Path::new(env!("CARGO_MANIFEST_DIR"));
                bench.parent().unwrap_or(bench).join("assets/textures")
            }
        });
        if !dir.is_dir() {
            bail!("{} is not a directory", dir.display());
        }
        Ok(dir)
    }
}

/// The options of a bench that runs the paper's cases.
#[derive(Args, Debug)]
pub struct RunArgs {
    #[command(flatten)]
    pub textures: Textures,
    /// Batch size K.
    #[arg(long, default_value_t = 64)]
    pub batch: usize,
    /// Repetitions (paper: of each configuration; lbg: of the end-to-end (b) run);
    /// the best is reported.
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
    /// Search threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Write the outputs into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

impl RunArgs {
    /// The search threads of the run.
    pub fn pool(&self) -> Result<rayon::ThreadPool> {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = self.threads {
            b = b.num_threads(t);
        }
        Ok(b.build()?)
    }

    /// Writes `image` as `name` into `--out`, if given.
    pub fn save(&self, name: &str, image: &ColorImage) -> Result<()> {
        if let Some(o) = &self.out {
            std::fs::create_dir_all(o)?;
            texsyn::imaging::save_color(&o.join(name), image)?;
        }
        Ok(())
    }
}

/// A binary built beside texsyn-bench (`name`), or `given`; it must exist.
pub fn sibling_binary(name: &str, given: Option<&Path>, flag: &str) -> Result<PathBuf> {
    let p = match given {
        Some(p) => p.to_path_buf(),
        None => std::env::current_exe()?
            .parent()
            .context("texsyn-bench has no directory")?
            .join(name),
    };
    anyhow::ensure!(
        p.is_file(),
        "no {name} binary at {}: build it (cargo build --release -p {name}) or give {flag}",
        p.display()
    );
    Ok(p)
}

/// Wall seconds and peak resident bytes of a child process (`wait4`), which
/// must exit with 0. A child's peak starts at its parent's when it is forked,
/// so callers go through [`measured`], whose helper process is small.
fn wait_measured(cmd: &mut Command) -> Result<(f64, u64)> {
    let t = Instant::now();
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {:?}", cmd.get_program()))?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value of the plain C struct.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `pid` is our own child, not yet waited for; both pointers are
    // to live locals.
    let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    let secs = t.elapsed().as_secs_f64();
    ensure!(
        r == pid,
        "wait4 failed: {}",
        std::io::Error::last_os_error()
    );
    ensure!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "{:?} failed (status {status})",
        cmd.get_program()
    );
    Ok((secs, usage.ru_maxrss as u64 * 1024))
}

/// A command to be timed: `program` run by `texsyn-bench measure-child`, a
/// fresh small process, so that the peak memory it reports is the program's
/// own and not this process's at the fork. Add arguments and stdio to `cmd`,
/// then [`Measured::run`].
pub struct Measured {
    pub cmd: Command,
    result: tempfile::TempPath,
}

pub fn measured(program: &Path) -> Result<Measured> {
    let result = tempfile::NamedTempFile::new()?.into_temp_path();
    let mut cmd = Command::new(std::env::current_exe()?);
    cmd.arg("measure-child")
        .arg("--result")
        .arg(&result)
        .arg("--")
        .arg(program);
    Ok(Measured { cmd, result })
}

impl Measured {
    /// Runs the program: its wall seconds and peak resident bytes.
    pub fn run(mut self) -> Result<(f64, u64)> {
        let status = self
            .cmd
            .status()
            .context("cannot start texsyn-bench measure-child")?;
        ensure!(status.success(), "the measured command failed ({status})");
        let text = std::fs::read_to_string(&self.result)?;
        let mut it = text.split_whitespace().map(str::parse::<f64>);
        match (it.next(), it.next()) {
            (Some(Ok(secs)), Some(Ok(bytes))) => Ok((secs, bytes as u64)),
            _ => bail!("measure-child wrote no result"),
        }
    }
}

/// `texsyn-bench measure-child`: runs a command and writes its wall seconds
/// and peak resident bytes into a file.
#[derive(clap::Args, Debug)]
pub struct MeasureChildArgs {
    #[arg(long)]
    pub result: PathBuf,
    /// The program and its arguments.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, required = true)]
    pub command: Vec<std::ffi::OsString>,
}

pub fn measure_child(a: &MeasureChildArgs) -> Result<()> {
    let mut cmd = Command::new(&a.command[0]);
    cmd.args(&a.command[1..]);
    let (secs, peak) = wait_measured(&mut cmd)?;
    std::fs::write(&a.result, format!("{secs} {peak}"))?;
    Ok(())
}
