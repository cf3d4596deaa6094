//! A whole `solid` run as the library does it: the views and maps read from
//! files (each file once), the weight volumes, the synthesis, and the output
//! directory written whole (ARCHITECTURE §11).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{ensure, Result};

use super::{replay, synthesize, MaterialWeights, Solid, SolidSettings, View};
use crate::imaging::volume::{Axis, Volume};
use crate::imaging::{self, ColorImage, OutputDir};
use crate::progress::Progress;
use crate::search::SearchBackend;

/// Largest edge of a solid.
pub const MAX_EDGE: usize = 4096;

/// A view named by its file: material (0-based), axis and image.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewFile {
    pub material: usize,
    pub axis: Axis,
    pub path: PathBuf,
}

/// Another map of the material replayed through the coordinates (§5.5):
/// its name (the output's file stem) and one map per view.
#[derive(Clone, Debug)]
pub struct ReplayFiles {
    pub name: String,
    pub paths: Vec<PathBuf>,
}

/// How the materials share the volume, as files.
#[derive(Clone, Debug)]
pub enum WeightFiles {
    Single,
    Ramp(Axis),
    /// One 1-channel volume header per material.
    Volumes(Vec<PathBuf>),
}

/// Everything one `solid` run reads, makes and writes.
#[derive(Clone, Debug)]
pub struct SolidJob {
    pub views: Vec<ViewFile>,
    pub size: [usize; 3],
    pub settings: SolidSettings,
    pub weights: WeightFiles,
    /// Axes whose PNG slices go into `slices/`.
    pub slices: Vec<Axis>,
    pub replays: Vec<ReplayFiles>,
    /// The output directory.
    pub output: PathBuf,
}

/// What a finished run reports.
pub struct SolidSummary {
    pub levels: usize,
    pub seconds: f64,
    /// The lattice phase's grid, as given or found (`None`: off).
    pub lattice: Option<crate::lattice::Lattice>,
}

impl SolidJob {
    /// The materials (one more than the largest view material).
    pub fn materials(&self) -> usize {
        self.views.iter().map(|v| v.material).max().unwrap_or(0) + 1
    }

    /// Checks the job before anything is read.
    pub fn validate(&self) -> Result<()> {
        let (h, passes) = (self.settings.base.histogram, self.settings.base.passes);
        ensure!(
            h.is_finite() && (0.0..=1.0).contains(&h),
            "--histogram {h} must be in [0, 1] (1: full matching, 0: the paper's plain method)"
        );
        ensure!(
            (1..=64).contains(&passes),
            "--passes {passes} must be in 1..=64"
        );
        let u = self.settings.index_histogram;
        ensure!(
            u.is_finite() && (0.0..=16.0).contains(&u),
            "--index-histogram {u} must be in [0, 16] (0: off, every exemplar pixel as free to take as the last)"
        );
        let b = self.settings.band_matching;
        ensure!(
            b <= super::MAX_BAND_MATCHING,
            "--band-matching {b} must be in 0..={} (0: off)",
            super::MAX_BAND_MATCHING
        );
        let k = self.settings.base.k;
        ensure!(
            (1..=crate::parallel::candidates::MAX_K).contains(&k),
            "--k {k} must be in 1..={}",
            crate::parallel::candidates::MAX_K
        );
        ensure!(
            self.size.iter().all(|&n| (1..=MAX_EDGE).contains(&n)),
            "every edge of the solid must be in 1..={MAX_EDGE}"
        );
        let mut names = std::collections::HashSet::new();
        for r in &self.replays {
            ensure!(
                names.insert(r.name.clone()),
                "two --replay maps are named {}; rename one",
                r.name
            );
            ensure!(
                !["solid", "preview", "slices"].contains(&r.name.as_str()),
                "--replay map '{}' would overwrite the solid's own output; rename the map",
                r.name
            );
            ensure!(
                r.paths.len() == self.views.len(),
                "one --replay map per view"
            );
        }
        let materials = self.materials();
        match &self.weights {
            WeightFiles::Single if materials > 1 => anyhow::bail!(
                "a morph of {materials} materials needs --ramp x|y|z or --weight-volumes W1.json,W2.json,..."
            ),
            WeightFiles::Volumes(v) => ensure!(
                v.len() == materials,
                "{} weight volumes for {materials} materials; give one per material, in order",
                v.len()
            ),
            _ => {}
        }
        Ok(())
    }

    /// Every input file, named by its flag.
    fn inputs(&self) -> Vec<(&'static str, &Path)> {
        let mut inputs: Vec<(&str, &Path)> = self
            .views
            .iter()
            .map(|v| ("--view", v.path.as_path()))
            .collect();
        if let WeightFiles::Volumes(v) = &self.weights {
            inputs.extend(v.iter().map(|p| ("--weight-volumes", p.as_path())));
        }
        for r in &self.replays {
            inputs.extend(r.paths.iter().map(|p| ("--replay", p.as_path())));
        }
        inputs
    }

    /// Reads the inputs, synthesises the solid through `backend` and writes
    /// the output directory (solid, preview, slices, replays) whole.
    pub fn run(
        &self,
        backend: &mut dyn SearchBackend,
        progress: &dyn Progress,
    ) -> Result<SolidSummary> {
        self.validate()?;
        let out_dir = OutputDir::create(&self.output, &self.inputs())?;
        let dir = out_dir.path().to_path_buf();
        // Inputs: each distinct file read once.
        let mut files: Vec<(PathBuf, ColorImage)> = Vec::new();
        let mut view_image = Vec::with_capacity(self.views.len());
        for v in &self.views {
            let k = match files.iter().position(|(p, _)| *p == v.path) {
                Some(k) => k,
                None => {
                    files.push((v.path.clone(), imaging::load_color(&v.path)?));
                    files.len() - 1
                }
            };
            view_image.push(k);
        }
        let weights = self.load_weights()?;
        let mut replay_maps = self.load_replays(|j| &files[view_image[j]].1)?;
        let mirrored = if self.settings.mirror {
            self.views_to_mirror(|j| &files[view_image[j]].1)
        } else {
            Vec::new()
        };
        for &j in &mirrored {
            let flipped = super::mirror::flipped(&files[view_image[j]].1);
            files.push((self.views[j].path.clone(), flipped));
            view_image[j] = files.len() - 1;
            for (_, _, maps) in &mut replay_maps {
                maps[j] = super::mirror::flipped(&maps[j]);
            }
            tracing::info!(
                axis = %self.views[j].axis.name(),
                "the view across this axis runs along its anti-diagonal; mirrored"
            );
        }
        let views: Vec<View> = self
            .views
            .iter()
            .zip(&view_image)
            .map(|(v, &k)| View {
                axis: v.axis,
                exemplar: &files[k].1,
                material: v.material,
            })
            .collect();
        let t = Instant::now();
        let mut out = synthesize(
            &views,
            &weights,
            self.size,
            &self.settings,
            backend,
            progress,
        )?;
        let seconds = t.elapsed().as_secs_f64();
        tracing::info!(seconds, levels = out.levels, "solid done");
        let mirrored_axes: Vec<Axis> = mirrored.iter().map(|&j| self.views[j].axis).collect();
        let info = self.info(&out, seconds, &mirrored_axes);
        let colour = Volume::new(self.size, 3, std::mem::take(&mut out.colour))?;
        write_volume(&colour, &dir, "solid", "preview.png", &info)?;
        if !self.slices.is_empty() {
            let slice_dir = dir.join("slices");
            std::fs::create_dir_all(&slice_dir)?;
            for axis in &self.slices {
                colour.save_slices(&slice_dir, *axis, mirrored_axes.contains(axis))?;
            }
        }
        for (name, channels, maps) in &replay_maps {
            let v = replay(&out, maps, *channels)?;
            write_volume(&v, &dir, name, &format!("{name}_preview.png"), &info)?;
        }
        out_dir.commit()?;
        Ok(SolidSummary {
            levels: out.levels,
            seconds,
            lattice: out.lattice,
        })
    }

    /// The material weights: a ramp, or the weight volumes read and checked.
    fn load_weights(&self) -> Result<MaterialWeights> {
        Ok(match &self.weights {
            WeightFiles::Single => MaterialWeights::Single,
            WeightFiles::Ramp(axis) => MaterialWeights::Ramp(*axis),
            WeightFiles::Volumes(paths) => {
                let mut vols = Vec::with_capacity(paths.len());
                for p in paths {
                    let (v, _) = Volume::load(p)?;
                    let s = self.size;
                    ensure!(
                        v.size == s && v.channels == 1,
                        "weight volume {} is {}×{}×{} with {} channels; it must be 1 channel of the solid's size {}×{}×{}",
                        p.display(), v.size[0], v.size[1], v.size[2], v.channels, s[0], s[1], s[2]
                    );
                    vols.push(v.data.iter().map(|&b| f32::from(b) / 255.0).collect());
                }
                MaterialWeights::Volumes(vols)
            }
        })
    }

    /// Every replay's maps, read and checked against their views'
    /// exemplars (`exemplar(j)`) before the synthesis: (name, channels, maps).
    fn load_replays<'a>(
        &self,
        exemplar: impl Fn(usize) -> &'a ColorImage,
    ) -> Result<Vec<(String, usize, Vec<ColorImage>)>> {
        let mut out = Vec::with_capacity(self.replays.len());
        for r in &self.replays {
            let mut maps = Vec::with_capacity(self.views.len());
            let mut channels = 1;
            for (j, p) in r.paths.iter().enumerate() {
                let map = imaging::load_image(p)?;
                let ex = exemplar(j);
                ensure!(
                    (map.width, map.height) == (ex.width, ex.height),
                    "--replay map {} is {}x{}, but the view {}:{} exemplar is {}x{}; give the map of that exemplar",
                    p.display(), map.width, map.height,
                    self.views[j].material + 1, self.views[j].axis.name(),
                    ex.width, ex.height
                );
                if map.format.colour_channels() > 1 {
                    channels = 3;
                }
                maps.push(map.search_colour());
            }
            out.push((r.name.clone(), channels, maps));
        }
        Ok(out)
    }

    /// The views to mirror ([`super::mirror`]), given each view's
    /// exemplar: only for one material seen once across each of x, y and z
    /// (one or two views can always agree).
    fn views_to_mirror<'a>(&self, exemplar: impl Fn(usize) -> &'a ColorImage) -> Vec<usize> {
        let mut seen = [false; 3];
        let once = self
            .views
            .iter()
            .all(|v| !std::mem::replace(&mut seen[v.axis.index()], true));
        if self.materials() != 1 || self.views.len() != 3 || !once {
            return Vec::new();
        }
        (0..self.views.len())
            .filter(|&j| super::mirror::to_mirror(super::mirror::gradient_correlation(exemplar(j))))
            .collect()
    }

    /// The header's description of the run.
    fn info(&self, out: &Solid, seconds: f64, mirrored: &[Axis]) -> serde_json::Value {
        let s = &self.settings;
        serde_json::json!({
            "method": "solid (Manke–Wünsche §5)",
            "views": self.views.iter().map(|v| serde_json::json!({
                "material": v.material + 1,
                "axis": v.axis.name().to_string(),
                "exemplar": v.path.display().to_string(),
            })).collect::<Vec<_>>(),
            "neighbourhood": s.base.neighbourhood.name(),
            "jitter": s.base.jitter,
            "passes": s.base.passes,
            "k": s.base.k,
            "histogram": s.base.histogram,
            "index_histogram": s.index_histogram,
            "band_matching": s.band_matching,
            "checker_cap": s.checker_cap,
            "slice_contrast": s.slice_contrast,
            "lattice": out.lattice.map(|l| l.period),
            "mirrored_views": mirrored.iter().map(|a| a.name().to_string()).collect::<Vec<_>>(),
            "seed": s.base.seed,
            "levels": out.levels,
            "appearance_components": out.dims,
            "explained_variance": out.explained_variance,
            "seconds": seconds,
        })
    }
}

fn write_volume(
    v: &Volume,
    dir: &Path,
    stem: &str,
    preview: &str,
    info: &serde_json::Value,
) -> Result<()> {
    v.save(dir, stem, Some(info.clone()))?;
    imaging::save_color(&dir.join(preview), &v.preview(4))
}
