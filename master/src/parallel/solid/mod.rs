//! Solid textures from 2-D views (Manke–Wünsche §5; ARCHITECTURE §11).
//!
//! Each *view* is a 2-D exemplar that shows the material cut across one axis
//! of the volume, and keeps its own volume of exemplar coordinates (§5.1).
//! Per level the coordinates are initialised or upsampled in the view's plane
//! and copied along the third axis (eq. 4), jittered by a hash of the 3-D
//! position, and corrected in eight sub-passes, a 2×2×2 pattern (§5.3). For a
//! voxel and a view, the neighbourhood is gathered in that view's plane from
//! the blend of every view's appearance (eq. 5), and the view takes the
//! k-coherence candidate that matches it best (eq. 3). Several materials,
//! each with its views, morph under weight volumes as the 2-D morph does
//! under weight maps (§4): a view's weight is its material's weight shared
//! evenly among the material's views.
//!
//! Plain, this washes out (Manke–Wünsche §6 note the smoothing): the blend
//! of views that do not yet agree is flatter than the exemplar, and the
//! views match its flatness. As Kopf et al. 2007 do, the solid's
//! histograms are matched to the exemplar's: the blend's appearance
//! components after every sub-pass, the output colour per channel at the
//! end ([`histogram`]). The colour's Laplacian bands are then matched to
//! the exemplars' as Heeger and Bergen do ([`bands`]), which restores part
//! of the crispness the blend of three views takes away, and every slice
//! across every axis is given the exemplars' contrast ([`contrast`]), which
//! the volume-wide matching leaves to where the low frequencies fall.

use anyhow::{bail, ensure, Result};

use super::appearance::Pca;
use super::driver::{blend, check_exemplar, run_levels, ParallelSettings};
use super::neighbourhood::Neighbourhood;
use crate::imaging::volume::Volume;
use crate::imaging::ColorImage;
use crate::lattice::{Lattice, LatticeSpec};
use crate::progress::Progress;
use crate::search::SearchBackend;

mod bands;
mod contrast;
mod job;
mod lattice;
pub mod mirror;
#[cfg(test)]
mod tests;
mod weights;

pub use bands::{ITERATIONS as BAND_MATCHING, MAX_ITERATIONS as MAX_BAND_MATCHING};
pub use job::{ReplayFiles, SolidJob, SolidSummary, ViewFile, WeightFiles, MAX_EDGE};
pub use lattice::SUB_PASSES;
pub use weights::ViewWeights;

pub use crate::imaging::volume::Axis;

/// One exemplar view: material `material` (0-based) seen across `axis`.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub axis: Axis,
    pub exemplar: &'a ColorImage,
    pub material: usize,
}

/// How the materials share the volume.
#[derive(Clone, Debug)]
pub enum MaterialWeights {
    /// One material everywhere.
    Single,
    /// A linear ramp along an axis: material `j` of `m` has weight 1 at the
    /// `j`-th of `m` evenly spaced stations and falls to 0 at the next ones
    /// (as the 2-D `--ramp`).
    Ramp(Axis),
    /// One weight volume per material (x fastest, then y, then z), any
    /// non-negative scale; normalised per voxel (all zero: evenly shared).
    Volumes(Vec<Vec<f32>>),
}

/// A finished solid.
pub struct Solid {
    pub size: [usize; 3],
    /// RGB per voxel, x fastest, then y, then z.
    pub colour: Vec<u8>,
    /// Per view, its finest-level exemplar coordinate at every voxel.
    pub coords: Vec<Vec<[u32; 2]>>,
    /// Every view's weight at every voxel of the finest level.
    pub weights: ViewWeights,
    pub levels: usize,
    /// Components of the appearance space and the variance they keep.
    pub dims: usize,
    pub explained_variance: f64,
    /// Strength of the colour's histogram matching (0: none, as for a
    /// morph of several materials), which [`replay`] applies too.
    pub colour_matching: f32,
    /// Rounds of the colour's band matching ([`bands`]; 0: none), which
    /// [`replay`] applies too, only where `colour_matching` is on.
    pub band_matching: usize,
    /// Whether the band-matched colour's slices have their pixel checker
    /// capped at the exemplars' ([`bands::cap_checker`]), which [`replay`]
    /// applies too.
    pub checker_cap: bool,
    /// Whether every slice's per-channel contrast is kept within
    /// [`contrast::BAND`] of the exemplars' ([`contrast::even_slices`]),
    /// which [`replay`] applies too.
    pub slice_contrast: bool,
    /// The lattice phase's grid, as given or found (`None`: off).
    pub lattice: Option<Lattice>,
}

/// Bytes a solid of `size` with `views` views, `materials` materials and
/// `dims` appearance components needs at its finest level: coordinates
/// (twice at the end, when they are split per view), the sub-pass's new
/// coordinates, the appearance blend and its histogram-matched copy, the
/// weight volumes (full size and level), and the colour (twice, as it is
/// written).
pub fn memory_needed(size: [usize; 3], views: usize, materials: usize, dims: usize) -> u64 {
    let v = size.iter().map(|&s| s as u64).product::<u64>();
    let m = views as u64;
    let weights = if materials > 1 {
        8 * materials as u64
    } else {
        0
    };
    v * (17 * m + 8 * dims as u64 + weights + 6)
}

/// Synthesises a solid of `size` voxels from `views`; a solid larger than
/// the memory limit is refused before any work, naming the memory it needs.
pub fn synthesize(
    views: &[View],
    weights: &MaterialWeights,
    size: [usize; 3],
    settings: &SolidSettings,
    backend: &mut dyn SearchBackend,
    progress: &dyn Progress,
) -> Result<Solid> {
    let s = &settings.base;
    ensure!(
        s.histogram.is_finite() && s.histogram >= 0.0,
        "the histogram matching strength must be 0 or more"
    );
    ensure!(
        !views.is_empty(),
        "no view to synthesise from; give --view AXIS=IMAGE"
    );
    ensure!(
        size.iter().all(|&n| n >= 1),
        "the solid size must not be empty"
    );
    if s.neighbourhood == Neighbourhood::Reduced {
        bail!(
            "the reduced neighbourhood fails in 3-D (Manke–Wünsche §5.4); use half (the default), 5 or 7"
        );
    }
    let materials = views.iter().map(|v| v.material).max().unwrap_or(0) + 1;
    for mat in 0..materials {
        let axes: Vec<Axis> = views
            .iter()
            .filter(|v| v.material == mat)
            .map(|v| v.axis)
            .collect();
        ensure!(
            !axes.is_empty(),
            "material {} has no view; number materials 1, 2, ... without gaps",
            mat + 1
        );
        for a in Axis::ALL {
            ensure!(
                axes.iter().filter(|&&b| b == a).count() <= 1,
                "material {} has two views across {}; give one exemplar per axis",
                mat + 1,
                a.name()
            );
        }
    }
    for v in views {
        check_exemplar(v.exemplar, &format!("the view across {}", v.axis.name()))?;
    }
    let grid = phase_grid(settings.lattice, views)?;
    let voxels = size.iter().product::<usize>();
    // Views that share an exemplar share its levels and candidate sets.
    let mut uniq: Vec<&ColorImage> = Vec::new();
    let view_ex: Vec<usize> = views
        .iter()
        .map(|v| {
            match uniq.iter().position(|u| {
                (u.width, u.height) == (v.exemplar.width, v.exemplar.height)
                    && u.rgb == v.exemplar.rgb
            }) {
                Some(k) => k,
                None => {
                    uniq.push(v.exemplar);
                    uniq.len() - 1
                }
            }
        })
        .collect();
    let pca = Pca::fit(&uniq)?;
    let dims = pca.components.len();
    let need = memory_needed(size, views.len(), materials, dims);
    s.budget.check(
        &format!(
            "a {}×{}×{} solid with {} views",
            size[0],
            size[1],
            size[2],
            views.len()
        ),
        need,
        "choose a smaller --size",
    )?;
    // Only now, with the memory checked, the full-size weights.
    let full_weights: Option<Vec<Vec<f32>>> = match weights {
        MaterialWeights::Single => {
            ensure!(
                materials == 1,
                "{materials} materials need weight volumes or a ramp"
            );
            None
        }
        MaterialWeights::Ramp(axis) => {
            (materials > 1).then(|| weights::ramp(materials, *axis, size))
        }
        MaterialWeights::Volumes(v) => {
            ensure!(
                v.len() == materials,
                "{} weight volumes for {materials} materials; give one per material",
                v.len()
            );
            ensure!(
                v.iter().all(|w| w.len() == voxels),
                "every weight volume must be {}×{}×{}, the solid's size",
                size[0],
                size[1],
                size[2]
            );
            let mut v = v.clone();
            crate::parallel::weights::normalise(&mut v);
            Some(v)
        }
    };
    let m = views.len();
    let mut volume = lattice::Volume {
        views,
        view_ex: &view_ex,
        size,
        seed: s.seed,
        histogram: s.histogram,
        index_histogram: settings.index_histogram,
        dims,
        full_weights,
        points3: Vec::new(),
        coords: Vec::new(),
        level_size: [0; 3],
        weights: None,
        blend: Vec::new(),
        matched: Vec::new(),
        phase: grid,
    };
    let levels = run_levels(&mut volume, &uniq, &pca, s, backend, progress)?.len();
    // The blend is done with; freed before the colour and the per-view
    // split, which are the peak.
    volume.blend = Vec::new();
    volume.matched = Vec::new();
    let coords = std::mem::take(&mut volume.coords);
    let weights = volume.weights.take().expect("at least one level");
    let per_view: Vec<Vec<[u32; 2]>> = (0..m)
        .map(|j| coords.iter().skip(j).step_by(m).copied().collect())
        .collect();
    drop(coords);
    let mut solid = Solid {
        size,
        colour: Vec::new(),
        coords: per_view,
        weights,
        levels,
        dims,
        explained_variance: pca.explained,
        colour_matching: if materials == 1 { s.histogram } else { 0.0 },
        band_matching: settings.band_matching,
        checker_cap: settings.checker_cap,
        slice_contrast: settings.slice_contrast,
        lattice: grid,
    };
    let exemplars: Vec<ColorImage> = views.iter().map(|v| v.exemplar.clone()).collect();
    solid.colour = replay(&solid, &exemplars, 3)?.data;
    Ok(solid)
}

/// Settings of a solid synthesis.
#[derive(Clone, Debug)]
pub struct SolidSettings {
    /// Neighbourhood (half, 5 or 7), jitter, passes, k, the histogram
    /// matching's strength and seed.
    pub base: ParallelSettings,
    /// Weight of the index histogram matching ([`lattice`]'s usage term;
    /// 0: off).
    pub index_histogram: f32,
    /// Rounds of the colour's band histogram matching ([`bands`]; 0: off).
    pub band_matching: usize,
    /// Cap the band-matched colour's pixel checker at the exemplars'
    /// ([`bands::cap_checker`]; only with band matching).
    pub checker_cap: bool,
    /// Keep every slice's contrast within [`contrast::BAND`] of the
    /// exemplars' ([`contrast::even_slices`]; only with histogram matching).
    pub slice_contrast: bool,
    /// Mirror one view where the three views of one material cannot agree
    /// as they are ([`mirror`]; the job does it, reading the files).
    pub mirror: bool,
    /// Lattice phase: the exemplars' grid, which every view keeps in phase
    /// with the voxels ([`crate::lattice::PHASE_TOLERANCE`]), as given, found in
    /// the exemplars ([`phase_grid`]; the default) or off.
    pub lattice: LatticeSpec,
}

/// `--lattice auto` keeps a grid found in the exemplars only where its
/// cells look alike: at most this share of the exemplar's colour variance
/// lies between them ([`Lattice::cell_share`]). The three views of a voxel
/// keep their grids in phase but each may copy another cell, so where every
/// cell has its own colour (the bundled coloured tiles, 0.70) they mix into
/// washed, false colours; a weave (burlap 0.004) and a mosaic of one kind
/// of tile (the facade, 0.22) keep their grid.
pub const CELLS_ALIKE: f64 = 0.5;

/// The lattice phase's grid for `views`: the given one, checked against
/// every exemplar, or for `auto` the grid [`crate::lattice::detect`] finds,
/// where every distinct exemplar shows the same one (periods within a
/// pixel) with cells alike ([`CELLS_ALIKE`]); none where one shows none,
/// they differ, or the cells do not look alike, since one grid holds every
/// view in phase.
fn phase_grid(spec: LatticeSpec, views: &[View]) -> Result<Option<Lattice>> {
    match spec {
        LatticeSpec::Off => Ok(None),
        LatticeSpec::Given(l) => {
            for v in views {
                l.validate([v.exemplar.width, v.exemplar.height])?;
            }
            Ok(Some(l))
        }
        LatticeSpec::Auto => {
            let mut seen: Vec<&ColorImage> = Vec::new();
            let mut grids = Vec::new();
            for v in views {
                if !seen
                    .iter()
                    .any(|e| std::ptr::eq(*e, v.exemplar) || **e == *v.exemplar)
                {
                    seen.push(v.exemplar);
                    grids.push(
                        crate::lattice::detect(v.exemplar).map(|l| (l, l.cell_share(v.exemplar))),
                    );
                }
            }
            let Some((first, _)) = grids[0] else {
                return Ok(None);
            };
            let same = |g: &Option<(Lattice, f64)>| match g {
                Some((l, _)) => (0..2).all(|i| (l.period[i] - first.period[i]).abs() <= 1.0),
                None => false,
            };
            if !grids.iter().all(same) {
                tracing::info!("the exemplars show different grids or none; no lattice phase");
                return Ok(None);
            }
            let share = grids.iter().flatten().map(|g| g.1).fold(0.0, f64::max);
            if share > CELLS_ALIKE {
                tracing::info!(
                    period = ?first.period,
                    cell_share = share,
                    "the exemplar's grid cells differ in colour; no lattice phase (--lattice WxH forces it)"
                );
                return Ok(None);
            }
            Ok(Some(first))
        }
    }
}

/// Default weight of the index histogram matching (ARCHITECTURE §11): on
/// pink marble and walnut at 128³ over three seeds it lowered the centre
/// slices' S_L by about a fifth (0.5, 2 and 4 did no better).
pub const INDEX_HISTOGRAM: f32 = 1.0;

/// Default k of a solid's k-coherence sets: 2, as Lefebvre and Hoppe use
/// (the plane's default is 4). Each view of each voxel compares `9·k`
/// candidates, and a 128³ solid of three views takes half the time of
/// k = 4 (ARCHITECTURE §11).
pub const K: usize = 2;

/// Default strength of the histogram matching: full (ARCHITECTURE §11).
pub const HISTOGRAM: f32 = crate::parallel::driver::DEFAULT_HISTOGRAM;

impl Default for SolidSettings {
    fn default() -> Self {
        Self {
            base: ParallelSettings {
                neighbourhood: Neighbourhood::Half,
                k: K,
                // A solid cannot copy a 2-D exemplar, and its coarse levels
                // are where the histogram matching sets its contrast:
                // measured, only jittering them halved the faces' contrast.
                every_level: true,
                histogram: HISTOGRAM,
                ..ParallelSettings::default()
            },
            index_histogram: INDEX_HISTOGRAM,
            band_matching: BAND_MATCHING,
            checker_cap: true,
            slice_contrast: true,
            mirror: true,
            lattice: LatticeSpec::Auto,
        }
    }
}

/// A map replayed through a solid's coordinates (§5.5): per voxel
/// `Σ Wʲ·Mʲ(Sʲ)`, rounded, with `channels` 1 (the map's grey) or 3; `maps`
/// holds one map per view, each its view's exemplar size. Each channel is
/// then band-matched ([`bands`]) and histogram-matched to the views' maps as
/// the colour is (so replaying the colour exemplars gives the solid's
/// colour).
pub fn replay(s: &Solid, maps: &[ColorImage], channels: usize) -> Result<Volume> {
    ensure!(maps.len() == s.coords.len(), "one map per view");
    ensure!(
        channels == 1 || channels == 3,
        "a replay has 1 or 3 channels"
    );
    let voxels = s.size.iter().product::<usize>();
    let data = blend(voxels, maps.len(), channels, |i, j| {
        let c = s.coords[j][i];
        (
            s.weights.at(j, i),
            maps[j].get(c[0] as usize, c[1] as usize),
        )
    });
    let mut data = data;
    // Every view's map with its weight (one material: evenly shared).
    let weighted: Vec<(&ColorImage, f64)> = maps
        .iter()
        .enumerate()
        .map(|(j, m)| (m, f64::from(s.weights.at(j, 0))))
        .collect();
    if s.colour_matching > 0.0 && s.band_matching > 0 {
        bands::match_bands(&mut data, s.size, channels, &weighted, s.band_matching);
    }
    if s.colour_matching > 0.0 && voxels > 0 {
        for ch in 0..channels {
            // The views' maps, each with its view's weight.
            let mut target = [0.0f64; 256];
            for (j, map) in maps.iter().enumerate() {
                let w = f64::from(s.weights.at(j, 0)) / map.len().max(1) as f64;
                for p in map.rgb.chunks_exact(3) {
                    target[usize::from(p[ch])] += w;
                }
            }
            crate::parallel::histogram::match_bytes(
                &mut data,
                channels,
                ch,
                &target,
                s.colour_matching,
            );
        }
    }
    if s.colour_matching > 0.0 && s.slice_contrast {
        contrast::even_slices(&mut data, s.size, channels, &weighted);
    }
    if s.colour_matching > 0.0 && s.band_matching > 0 && s.checker_cap {
        bands::cap_checker(&mut data, s.size, channels, &weighted);
    }
    Volume::new(s.size, channels, data)
}
