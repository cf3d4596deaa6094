//! `texsyn solid`: solid textures from 2-D views (ARCHITECTURE §11) from the
//! command line.

use std::path::PathBuf;

use anyhow::{bail, ensure, Context, Result};
use clap::Args;

use super::parallel::{parse_jitter, parse_neighbourhood};
use super::progress::Bars;
use super::RunArgs;
use crate::imaging::volume::Axis;
use crate::lattice::LatticeSpec;
use crate::parallel::solid::{
    self, ReplayFiles, SolidJob, SolidSettings, ViewFile, WeightFiles, MAX_EDGE,
};
use crate::parallel::synth::ParallelSettings;

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
    /// k of the k-coherence candidate sets (1 to 16): each view of each voxel
    /// compares 9·k candidates.
    #[arg(long, default_value_t = solid::K)]
    pub k: usize,
    /// Strength of the histogram matching that keeps the solid's contrast,
    /// 0 to 1 (1: full; 0: the paper's plain method, which washes out).
    #[arg(long, default_value_t = solid::HISTOGRAM)]
    pub histogram: f32,
    /// Weight of the index histogram matching: a candidate exemplar pixel
    /// that the volume's views already take more often than an even share
    /// has its distance scaled by 1 + W·(uses/share − 1), so rare features
    /// (thin veins) are used as often as the exemplar holds them (0: off).
    #[arg(long, default_value_t = solid::INDEX_HISTOGRAM, value_name = "W")]
    pub index_histogram: f32,
    /// Rounds of band histogram matching of the colour (Heeger–Bergen): each
    /// colour component's Laplacian bands over the volume are matched to
    /// the exemplars', after the pixel checker is filtered out, so thin
    /// veins and fine grain come nearer the exemplars' crispness (0: off;
    /// only with --histogram above 0 and one material).
    #[arg(long, default_value_t = solid::BAND_MATCHING, value_name = "ROUNDS")]
    pub band_matching: usize,
    /// Leave the band-matched colour's pixel checker as it comes: by
    /// default each slice's energy at the pixel Nyquist frequency is damped
    /// to under the exemplars' where it is above (only slices over it
    /// change).
    #[arg(long)]
    pub no_checker_cap: bool,
    /// Leave each slice's contrast as the volume's histogram matching gives
    /// it: by default every slice across every axis is scaled about its
    /// mean until its standard deviation per channel is within 10 % of the
    /// exemplars' (a solid's slices otherwise range from about 0.65 to 1.15
    /// of it, where the volume's low frequencies fall).
    #[arg(long)]
    pub no_slice_contrast: bool,
    /// Lattice phase, for exemplars on a regular grid (a weave, tiles, a
    /// mosaic): the grid's period WxH in exemplar pixels (fractions allowed,
    /// e.g. 13.7x16; 0 leaves an axis free). Every view's coordinates are
    /// kept within a pixel of the grid's phase at the voxel, so the slices
    /// show the grid instead of blotches; it applies to every view. The
    /// default, `auto`, finds the grid in the exemplars where every distinct
    /// exemplar shows the same one and its cells look alike (a weave, one
    /// kind of tile; not tiles of many colours, whose views would mix), and
    /// runs without the phase elsewhere; `none` turns it off
    #[arg(long, value_name = "WxH|auto|none", value_parser = super::args::parse_lattice)]
    pub lattice: Option<crate::lattice::LatticeSpec>,
    /// Keep every view as given: by default, where the three views of one
    /// material cannot agree (their gradient correlations, streaks along the
    /// exemplar's anti-diagonal on all three, have no solid), one view's
    /// exemplar is mirrored top to bottom and its slices are written back
    /// in the exemplar's frame.
    #[arg(long)]
    pub no_mirror: bool,
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
    /// Keep each level's k-coherence candidate sets in this directory: a
    /// later solid from the same views skips their search (same output).
    #[arg(long, value_name = "DIR")]
    pub candidate_cache: Option<PathBuf>,
    #[command(flatten)]
    pub run: RunArgs,
}

/// Parses `[M:]AXES=PATH` into one spec per axis.
fn parse_view(s: &str, flag: &str) -> Result<Vec<ViewFile>> {
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
    let mut out: Vec<ViewFile> = Vec::new();
    for c in axes.trim().chars() {
        let axis = Axis::parse(c)
            .with_context(|| format!("'{c}' in {flag} '{s}' is not an axis; use x, y or z"))?;
        ensure!(
            out.iter().all(|v| v.axis != axis),
            "{flag} '{s}' names axis {c} twice"
        );
        out.push(ViewFile {
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

fn parse_replay(s: &str, views: &[ViewFile]) -> Result<ReplayFiles> {
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
    Ok(ReplayFiles { name, paths })
}

impl TryFrom<&SolidArgs> for SolidJob {
    type Error = anyhow::Error;

    fn try_from(a: &SolidArgs) -> Result<Self> {
        let mut views = Vec::new();
        for v in &a.views {
            views.extend(parse_view(v, "--view")?);
        }
        let base = ParallelSettings {
            neighbourhood: parse_neighbourhood(&a.neighbourhood)?,
            jitter: parse_jitter(&a.jitter)?,
            seed: a.seed,
            passes: a.passes,
            k: a.k,
            histogram: a.histogram,
            budget: a.run.budget(),
            cache: super::parallel::open_cache(a.candidate_cache.as_deref())?,
            ..SolidSettings::default().base
        };
        let replays = a
            .replay
            .iter()
            .map(|r| parse_replay(r, &views))
            .collect::<Result<Vec<_>>>()?;
        let weights = match (&a.ramp, a.weight_volumes.is_empty()) {
            (Some(r), _) => {
                let mut c = r.trim().chars();
                match (c.next().and_then(Axis::parse), c.next()) {
                    (Some(axis), None) => WeightFiles::Ramp(axis),
                    _ => bail!("--ramp '{r}' is not x, y or z"),
                }
            }
            (None, false) => WeightFiles::Volumes(a.weight_volumes.clone()),
            (None, true) => WeightFiles::Single,
        };
        let job = SolidJob {
            views,
            size: parse_size3(&a.size)?,
            settings: SolidSettings {
                base,
                index_histogram: a.index_histogram,
                band_matching: a.band_matching,
                checker_cap: !a.no_checker_cap,
                slice_contrast: !a.no_slice_contrast,
                mirror: !a.no_mirror,
                lattice: a.lattice.unwrap_or(LatticeSpec::Auto),
            },
            weights,
            slices: parse_slices(&a.slices)?,
            replays,
            output: a.output.clone(),
        };
        job.validate()?;
        Ok(job)
    }
}

/// `texsyn solid`.
pub fn run(a: &SolidArgs) -> Result<()> {
    let job = SolidJob::try_from(a)?;
    let pool = a.run.pool()?;
    // Exemplar sizes are known only once read; LBG's probes are checked per level.
    let mut opened = a.run.open(a.seed, 0)?;
    let bars = Bars::new(a.run.quiet);
    let summary = pool.install(|| job.run(&mut opened.search, &bars))?;
    match (a.lattice, summary.lattice) {
        (None | Some(LatticeSpec::Auto), Some(found)) => {
            super::report_found_lattice(Some(found), a.run.quiet);
        }
        (Some(LatticeSpec::Auto), None) => super::report_found_lattice(None, a.run.quiet),
        _ => {}
    }
    if !a.run.quiet {
        let s = job.size;
        eprintln!(
            "wrote {} ({}×{}×{}, {} levels, {:.2} s)",
            a.output.display(),
            s[0],
            s[1],
            s[2],
            summary.levels,
            summary.seconds
        );
    }
    Ok(())
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
