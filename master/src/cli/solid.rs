//! `texsyn solid`: solid textures from 2-D views (ARCHITECTURE §11) from the
//! command line.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use clap::Args;

use super::parallel::{parse_jitter, parse_neighbourhood};
use super::progress::Bars;
use super::RunArgs;
use crate::imaging::volume::{Axis, Volume};
use crate::imaging::{self, ColorImage};
use crate::parallel::solid::{self, MaterialWeights, SolidSettings, View};
use crate::parallel::synth::ParallelSettings;

/// Largest edge of a solid.
pub const MAX_EDGE: usize = 4096;

#[derive(Args, Debug)]
pub struct SolidArgs {
    /// A view of the material: [M:]AXES=IMAGE. AXES is one or more of x, y, z
    /// (`xyz=marble.png` puts one exemplar on all three); M numbers the
    /// material of a morph (1 when left out). Repeat for each view.
    #[arg(long = "view", required = true, value_name = "[M:]AXES=IMAGE")]
    pub views: Vec<String>,
    /// The solid's size: N for an N×N×N cube, or XxYxZ.
    #[arg(long)]
    pub size: String,
    /// Output directory: solid.raw with its header solid.json, preview.png
    /// (faces and centre slices) and slices/.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Neighbourhood in each view's plane: half (half-reduced), 5 or 7.
    #[arg(long, alias = "neighborhood", default_value = "half")]
    pub neighbourhood: String,
    /// Jitter strength r in [0, 1], or one per level, coarsest first (r1,r2,...).
    #[arg(long, default_value = "0.4")]
    pub jitter: String,
    /// Random seed of the jitter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Correction passes per level (each of 8 sub-passes).
    #[arg(long, default_value_t = 2)]
    pub passes: usize,
    /// Strength of the histogram matching that keeps the solid's contrast
    /// (0: the paper's plain method, which washes out).
    #[arg(long, default_value_t = solid::HISTOGRAM)]
    pub histogram: f32,
    /// Morph the materials along a ramp across x, y or z: material 1 at the
    /// start, the last at the end.
    #[arg(long, conflicts_with = "weight_volumes")]
    pub ramp: Option<String>,
    /// Weight volumes, one per material, comma-separated: headers (.json) of
    /// 1-channel volumes of the solid's size, as `solid` writes them.
    #[arg(long, value_delimiter = ',')]
    pub weight_volumes: Vec<PathBuf>,
    /// PNG slices to write into slices/: none, x, y, z (default) or all.
    #[arg(long, default_value = "z")]
    pub slices: String,
    /// Another map of the material (height, roughness...) copied through the
    /// coordinates with no new search: MAP for every view (each view's
    /// exemplar must be the map's size), or [M:]AXES=MAP,... naming a map for
    /// every view. Written as a volume named after the first map, with its
    /// preview. Repeat for more maps.
    #[arg(long = "replay", value_name = "MAP | [M:]AXES=MAP,...")]
    pub replay: Vec<String>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// One parsed `[M:]AXES=PATH`.
#[derive(Clone, Debug, PartialEq)]
struct ViewSpec {
    material: usize,
    axis: Axis,
    path: PathBuf,
}

/// Parses `[M:]AXES=PATH` into one spec per axis.
fn parse_view(s: &str, flag: &str) -> Result<Vec<ViewSpec>> {
    let (lhs, path) = s.split_once('=').with_context(|| {
        format!(
            "{flag} '{s}' is not [M:]AXES=IMAGE, e.g. {flag} xyz=marble.png or {flag} 2:z=moss.png"
        )
    })?;
    ensure!(!path.is_empty(), "{flag} '{s}' names no image after '='");
    let (material, axes) = match lhs.split_once(':') {
        Some((m, a)) => {
            let m: usize = m
                .trim()
                .parse()
                .with_context(|| format!("material '{m}' in {flag} '{s}' is not a number"))?;
            ensure!(m >= 1, "materials are numbered from 1 ({flag} '{s}')");
            (m - 1, a)
        }
        None => (0, lhs),
    };
    ensure!(
        !axes.trim().is_empty(),
        "{flag} '{s}' names no axis; give x, y, z or a combination such as xyz"
    );
    let mut out: Vec<ViewSpec> = Vec::new();
    for c in axes.trim().chars() {
        let axis = Axis::parse(c)
            .with_context(|| format!("'{c}' in {flag} '{s}' is not an axis; use x, y or z"))?;
        ensure!(
            out.iter().all(|v| v.axis != axis),
            "{flag} '{s}' names axis {c} twice"
        );
        out.push(ViewSpec {
            material,
            axis,
            path: PathBuf::from(path),
        });
    }
    Ok(out)
}

/// Parses `N` or `XxYxZ`.
pub fn parse_size3(s: &str) -> Result<[usize; 3]> {
    let d = super::parse_dims(s, "--size", &[1, 3], "128 or --size 128x128x64")?;
    let size = if d.len() == 1 {
        [d[0]; 3]
    } else {
        [d[0], d[1], d[2]]
    };
    ensure!(
        size.iter().all(|&n| (1..=MAX_EDGE).contains(&n)),
        "--size '{s}': every edge must be in 1..={MAX_EDGE}"
    );
    Ok(size)
}

fn parse_slices(s: &str) -> Result<Vec<Axis>> {
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "none" => vec![],
        "all" => Axis::ALL.to_vec(),
        one => {
            let mut c = one.chars();
            match (c.next().and_then(Axis::parse), c.next()) {
                (Some(a), None) => vec![a],
                _ => bail!("--slices '{s}' is not none, x, y, z or all"),
            }
        }
    })
}

/// A `--replay` argument resolved to one map path per view.
struct Replay {
    name: String,
    /// Per view, the map's path.
    paths: Vec<PathBuf>,
}

fn parse_replay(s: &str, views: &[ViewSpec]) -> Result<Replay> {
    let paths: Vec<PathBuf> = if s.contains('=') {
        let mut specs = Vec::new();
        for part in s.split(',') {
            specs.extend(parse_view(part, "--replay")?);
        }
        views
            .iter()
            .map(|v| {
                specs
                    .iter()
                    .find(|r| (r.material, r.axis) == (v.material, v.axis))
                    .map(|r| r.path.clone())
                    .with_context(|| {
                        format!(
                            "--replay '{s}' has no map for the view {}:{}; name one for every view",
                            v.material + 1,
                            v.axis.name()
                        )
                    })
            })
            .collect::<Result<_>>()?
    } else {
        vec![PathBuf::from(s); views.len()]
    };
    let name = paths[0]
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .filter(|n| !n.is_empty())
        .with_context(|| format!("--replay '{s}' names no file"))?;
    ensure!(
        name != "solid" && name != "preview" && name != "slices",
        "--replay map '{name}' would overwrite the solid's own output; rename the map"
    );
    Ok(Replay { name, paths })
}

/// `texsyn solid`.
pub fn run(a: &SolidArgs) -> Result<()> {
    let size = parse_size3(&a.size)?;
    let mut specs = Vec::new();
    for v in &a.views {
        specs.extend(parse_view(v, "--view")?);
    }
    let base = ParallelSettings {
        neighbourhood: parse_neighbourhood(&a.neighbourhood)?,
        jitter: parse_jitter(&a.jitter)?,
        seed: a.seed,
        passes: a.passes,
        budget: a.run.budget(),
        ..ParallelSettings::default()
    };
    ensure!(
        a.histogram.is_finite() && (0.0..=100.0).contains(&a.histogram),
        "--histogram {} must be in [0, 100] (0: the paper's plain method)",
        a.histogram
    );
    ensure!(
        (1..=64).contains(&a.passes),
        "--passes {} must be in 1..=64",
        a.passes
    );
    let slices = parse_slices(&a.slices)?;
    let replays = a
        .replay
        .iter()
        .map(|r| parse_replay(r, &specs))
        .collect::<Result<Vec<_>>>()?;
    let mut names = std::collections::HashSet::new();
    for r in &replays {
        ensure!(
            names.insert(r.name.clone()),
            "two --replay maps are named {}; rename one",
            r.name
        );
    }
    let materials = specs.iter().map(|v| v.material).max().unwrap_or(0) + 1;
    let ramp = a
        .ramp
        .as_deref()
        .map(|r| {
            let mut c = r.trim().chars();
            match (c.next().and_then(Axis::parse), c.next()) {
                (Some(axis), None) => Ok(axis),
                _ => bail!("--ramp '{r}' is not x, y or z"),
            }
        })
        .transpose()?;
    if materials > 1 {
        ensure!(
            ramp.is_some() || !a.weight_volumes.is_empty(),
            "a morph of {materials} materials needs --ramp x|y|z or --weight-volumes W1.json,W2.json,..."
        );
    }
    ensure!(
        a.weight_volumes.is_empty() || a.weight_volumes.len() == materials,
        "{} weight volumes for {materials} materials; give one per material, in order",
        a.weight_volumes.len()
    );

    // Outputs: a directory written whole at the end, never holding an input.
    let mut in_refs: Vec<(&str, &Path)> =
        specs.iter().map(|v| ("--view", v.path.as_path())).collect();
    in_refs.extend(
        a.weight_volumes
            .iter()
            .map(|p| ("--weight-volumes", p.as_path())),
    );
    for r in &replays {
        in_refs.extend(r.paths.iter().map(|p| ("--replay", p.as_path())));
    }
    let out_dir = imaging::OutputDir::create(&a.output, &in_refs)?;
    let dir = out_dir.path().to_path_buf();
    let slice_dir = dir.join("slices");
    if !slices.is_empty() {
        std::fs::create_dir_all(&slice_dir).with_context(|| {
            format!("cannot create the slice directory {}", slice_dir.display())
        })?;
    }

    // Inputs: each distinct file read once.
    let mut files: Vec<(PathBuf, ColorImage)> = Vec::new();
    let mut view_image = Vec::with_capacity(specs.len());
    for v in &specs {
        let k = match files.iter().position(|(p, _)| *p == v.path) {
            Some(k) => k,
            None => {
                files.push((v.path.clone(), imaging::load_color(&v.path)?));
                files.len() - 1
            }
        };
        view_image.push(k);
    }
    let voxels = size.iter().product::<usize>();
    let weights = if let Some(axis) = ramp {
        MaterialWeights::Ramp(axis)
    } else if !a.weight_volumes.is_empty() {
        let mut vols = Vec::with_capacity(materials);
        for p in &a.weight_volumes {
            let (v, _) = Volume::load(p)?;
            ensure!(
                v.size == size && v.channels == 1,
                "weight volume {} is {}×{}×{} with {} channels; it must be 1 channel of the solid's size {}×{}×{}",
                p.display(),
                v.size[0],
                v.size[1],
                v.size[2],
                v.channels,
                size[0],
                size[1],
                size[2]
            );
            vols.push(
                v.data
                    .iter()
                    .map(|&b| f32::from(b) / 255.0)
                    .collect::<Vec<f32>>(),
            );
        }
        debug_assert!(vols.iter().all(|v| v.len() == voxels));
        MaterialWeights::Volumes(vols)
    } else {
        MaterialWeights::Single
    };
    // Replay maps, checked before the synthesis.
    let mut replay_maps: Vec<(String, usize, Vec<ColorImage>)> = Vec::new();
    for r in &replays {
        let mut maps = Vec::with_capacity(specs.len());
        let mut channels = 1;
        for (j, p) in r.paths.iter().enumerate() {
            let map = imaging::load_image(p)?;
            let ex = &files[view_image[j]].1;
            ensure!(
                (map.width, map.height) == (ex.width, ex.height),
                "--replay map {} is {}x{}, but the view {}:{} exemplar is {}x{}; give the map of that exemplar",
                p.display(),
                map.width,
                map.height,
                specs[j].material + 1,
                specs[j].axis.name(),
                ex.width,
                ex.height
            );
            if map.format.colour_channels() > 1 {
                channels = 3;
            }
            maps.push(map.search_colour());
        }
        replay_maps.push((r.name.clone(), channels, maps));
    }

    let views: Vec<View> = specs
        .iter()
        .zip(&view_image)
        .map(|(v, &k)| View {
            axis: v.axis,
            exemplar: &files[k].1,
            material: v.material,
        })
        .collect();
    let settings = SolidSettings {
        base,
        histogram: a.histogram,
    };
    let pool = a.run.pool()?;
    let largest = files
        .iter()
        .map(|(_, e)| e.width * e.height)
        .max()
        .unwrap_or(0);
    let mut opened = a.run.open(a.seed, largest)?;
    let bars = Bars::new(a.run.quiet);
    let t = Instant::now();
    let mut out = pool.install(|| {
        solid::synthesize(&views, &weights, size, &settings, &mut opened.search, &bars)
    })?;
    let seconds = t.elapsed().as_secs_f64();
    tracing::info!(seconds, levels = out.levels, "solid done");

    let info = serde_json::json!({
        "method": "solid (Manke–Wünsche §5)",
        "views": specs.iter().map(|v| serde_json::json!({
            "material": v.material + 1,
            "axis": v.axis.name().to_string(),
            "exemplar": v.path.display().to_string(),
        })).collect::<Vec<_>>(),
        "neighbourhood": a.neighbourhood,
        "jitter": settings.base.jitter,
        "passes": a.passes,
        "histogram": a.histogram,
        "seed": a.seed,
        "levels": out.levels,
        "appearance_components": out.dims,
        "explained_variance": out.explained_variance,
        "seconds": seconds,
    });
    let colour = Volume::new(size, 3, std::mem::take(&mut out.colour))?;
    write_volume(&colour, &dir, "solid", "preview.png", Some(info.clone()))?;
    for axis in &slices {
        colour.save_slices(&slice_dir, *axis)?;
    }
    for (name, channels, maps) in &replay_maps {
        let v = solid::replay(&out, maps, *channels)?;
        write_volume(
            &v,
            &dir,
            name,
            &format!("{name}_preview.png"),
            Some(info.clone()),
        )?;
    }
    out_dir.commit()?;
    if !a.run.quiet {
        eprintln!(
            "wrote {} ({}×{}×{}, {} levels, {seconds:.2} s)",
            a.output.display(),
            size[0],
            size[1],
            size[2],
            out.levels
        );
    }
    Ok(())
}

fn write_volume(
    v: &Volume,
    dir: &Path,
    stem: &str,
    preview: &str,
    info: Option<serde_json::Value>,
) -> Result<()> {
    v.save(dir, stem, info)?;
    imaging::save_color(&dir.join(preview), &v.preview(4))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_and_sizes_parse() {
        let v = parse_view("2:xz=a.png", "--view").unwrap();
        assert_eq!(v.len(), 2);
        assert_eq!((v[0].material, v[0].axis), (1, Axis::X));
        assert_eq!((v[1].material, v[1].axis), (1, Axis::Z));
        assert!(parse_view("w=a.png", "--view").is_err());
        assert!(parse_view("xx=a.png", "--view").is_err());
        assert!(parse_view("0:x=a.png", "--view").is_err());
        assert!(parse_view("a.png", "--view").is_err());
        assert_eq!(parse_size3("64").unwrap(), [64; 3]);
        assert_eq!(parse_size3("8x9x10").unwrap(), [8, 9, 10]);
        assert!(parse_size3("8x9").is_err());
        assert!(parse_size3("0").is_err());
        assert!(parse_size3("100000").is_err());
    }
}
