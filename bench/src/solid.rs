//! `texsyn-bench solid`: solid textures from 2-D views (ARCHITECTURE §11).
//! Each size and neighbourhood runs `texsyn solid` as a child process, so
//! its wall time and peak memory are its own (Manke–Wünsche §6 time 128³ at
//! little more than 5 min half-reduced and up to 15 min 7×7 on one 2.13 GHz
//! core); then `texsyn compare`'s measures of every face and centre slice of
//! the last solid against its exemplar.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Result};
use clap::Args;
use texsyn::compare;
use texsyn::imaging::volume::{Axis, Volume};
use texsyn::imaging::{self, ColorImage};

use crate::cases::Textures;

#[derive(Args, Debug)]
pub struct SolidArgs {
    #[command(flatten)]
    pub textures: Textures,
    /// The exemplar, on all three axes (in --textures, or a path).
    #[arg(long, default_value = "pink_marble_color_128.png")]
    pub exemplar: String,
    /// Edges of the cubes.
    #[arg(long, default_value = "64,128,256", value_delimiter = ',')]
    pub sizes: Vec<usize>,
    /// Neighbourhoods.
    #[arg(long, default_value = "half,7", value_delimiter = ',')]
    pub neighbourhoods: Vec<String>,
    /// Threads of each run (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Keep the solids in this directory (default: a temporary one).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The texsyn binary (default: next to texsyn-bench).
    #[arg(long)]
    pub texsyn: Option<PathBuf>,
}

pub fn run(a: &SolidArgs) -> Result<()> {
    let exemplar = {
        let p = PathBuf::from(&a.exemplar);
        if p.is_file() {
            p
        } else {
            a.textures.dir()?.join(&a.exemplar)
        }
    };
    ensure!(exemplar.is_file(), "no exemplar {}", exemplar.display());
    let texsyn = crate::cases::sibling_binary("texsyn", a.texsyn.as_deref(), "--texsyn")?;
    let tmp = tempfile::tempdir()?;
    let out = a.out.clone().unwrap_or_else(|| tmp.path().to_path_buf());
    println!(
        "solid from {} on x, y and z | threads {}",
        exemplar.display(),
        a.threads.map_or("all".into(), |t| t.to_string())
    );
    println!("| size | neighbourhood | time | peak memory |");
    println!("|---|---|---|---|");
    let mut last = None;
    for &n in &a.sizes {
        for nb in &a.neighbourhoods {
            let dir = out.join(format!("solid_{n}_{nb}"));
            let mut m = crate::cases::measured(&texsyn)?;
            let cmd = &mut m.cmd;
            cmd.arg("solid")
                .arg("--view")
                .arg(format!("xyz={}", exemplar.display()))
                .args(["--size", &n.to_string(), "--neighbourhood", nb])
                .args(["--slices", "none", "-q", "-o"])
                .arg(&dir);
            if let Some(t) = a.threads {
                cmd.args(["--threads", &t.to_string()]);
            }
            let (secs, peak) = m.run()?;
            println!(
                "| {n}³ | {nb} | {secs:.1} s | {:.0} MiB |",
                peak as f64 / (1u64 << 20) as f64
            );
            last = Some(dir);
        }
    }
    if let Some(dir) = last {
        faces(&dir, &imaging::load_color(&exemplar)?)?;
    }
    Ok(())
}

/// `compare`'s S_F, S_L and colour of every face and centre slice.
fn faces(dir: &Path, ex: &ColorImage) -> Result<()> {
    let (v, _) = Volume::load(&dir.join("solid.json"))?;
    println!(
        "\nfaces of {} against the exemplar (S_F higher is better; S_L, colour lower)",
        dir.display()
    );
    println!("| slice | S_F | S_L | colour |");
    println!("|---|---|---|---|");
    for axis in Axis::ALL {
        let n = v.size[axis.index()];
        for (what, at) in [("0", 0), ("far", n - 1), ("centre", n / 2)] {
            let f = v.slice_rgb(axis, at);
            println!(
                "| {} {what} | {:.3} | {:.3} | {:.4} |",
                axis.name(),
                compare::spectrum_similarity(ex, &f)?,
                compare::laplacian_distance(ex, &f)?,
                compare::colour_distance(ex, &f)
            );
        }
    }
    Ok(())
}
