//! The catalogue (Bourque–Dudek §3.2.1): each shader's parameter domain
//! sampled by adaptive subdivision, every sample rendered once and kept as
//! its structure descriptor and admissibility. Built once, saved as JSON,
//! rebuilt when the shader library changes.
//!
//! Subdivision: the domain is a box whose centre is the first sample. The
//! cells with the highest priority are split in half along their widest
//! parameter (whole numbers split between values) and their halves' centres
//! rendered; a half's priority is how far its centre's texture is from its
//! parent's, plus a small floor, times its width. So the catalogue is dense
//! where the texture changes fast with the parameters and sparse where it
//! does not. Cells are split in fixed batches, so the samples are the same
//! for any thread count.

use std::collections::BinaryHeap;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::descriptor::Structure;
use super::shaders::{Kind, Shader, LIBRARY};
use crate::imaging;

/// The file format's version; a catalogue of another version is rebuilt.
pub const VERSION: u32 = 1;
/// Largest catalogue file read (the default catalogue is a few MiB).
const MAX_CATALOGUE_BYTES: u64 = 256 << 20;
/// Render side of the catalogue's samples (and of the matching analysis).
pub const DEFAULT_SIZE: usize = 128;
/// Samples per shader (the paper's catalogues held about 200).
pub const DEFAULT_SAMPLES: usize = 200;
/// Catalogue neighbours averaged in the admissibility A(x).
const ADMISSIBILITY_NEIGHBOURS: usize = 6;
/// Cells split per round.
const BATCH: usize = 8;

/// What to build.
#[derive(Clone, Debug)]
pub struct BuildSettings {
    /// Render side in pixels (the unit square).
    pub size: usize,
    /// Samples per shader.
    pub samples: usize,
    /// Only these shaders (default: the whole library).
    pub shaders: Option<Vec<String>>,
}

impl Default for BuildSettings {
    fn default() -> Self {
        Self {
            size: DEFAULT_SIZE,
            samples: DEFAULT_SAMPLES,
            shaders: None,
        }
    }
}

impl BuildSettings {
    /// Refuses sizes and counts that cannot work.
    pub fn validate(&self) -> Result<()> {
        ensure!(
            (32..=512).contains(&self.size),
            "catalogue size {} must be in 32..=512 pixels",
            self.size
        );
        ensure!(
            (8..=5000).contains(&self.samples),
            "catalogue samples {} per shader must be in 8..=5000",
            self.samples
        );
        selected(self.shaders.as_deref())?;
        Ok(())
    }
}

/// The shaders named in `names` (all when none), refusing unknown names.
pub fn selected(names: Option<&[String]>) -> Result<Vec<&'static Shader>> {
    let Some(names) = names else {
        return Ok(LIBRARY.iter().collect());
    };
    ensure!(!names.is_empty(), "no shader selected; name at least one");
    names
        .iter()
        .map(|n| {
            super::shaders::by_name(n.trim()).with_context(|| {
                format!(
                    "unknown shader '{n}'; the library has {}",
                    LIBRARY
                        .iter()
                        .map(|s| s.name)
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })
        })
        .collect()
}

/// One rendered sample of a shader.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Sample {
    pub params: Vec<f64>,
    pub structure: Structure,
    /// A(x): mean similarity to the nearest catalogue samples over their
    /// distance in the unit parameter box (§3.2.1); higher = smoother.
    pub admissibility: f64,
}

/// A shader's samples.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ShaderSamples {
    pub shader: String,
    /// `name:min:max:kind` per parameter: a changed declaration is refused.
    pub signature: Vec<String>,
    pub samples: Vec<Sample>,
}

/// The catalogue of every shader.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Catalogue {
    pub version: u32,
    pub size: usize,
    pub shaders: Vec<ShaderSamples>,
}

fn signature(s: &Shader) -> Vec<String> {
    s.params
        .iter()
        .map(|p| format!("{}:{}:{}:{:?}", p.name, p.min, p.max, p.kind))
        .collect()
}

/// A box of the parameter domain, `lo..=hi` per parameter.
#[derive(Clone, Debug)]
struct Cell {
    lo: Vec<f64>,
    hi: Vec<f64>,
    /// The sample at the centre.
    centre: usize,
    /// The sample at the centre of the cell this one was split from.
    parent: usize,
}

impl Cell {
    /// The widest parameter as a fraction of its range, 0 if none can split.
    fn widest(&self, s: &Shader) -> (usize, f64) {
        let mut best = (0, 0.0);
        for (i, p) in s.params.iter().enumerate() {
            let w = match p.kind {
                Kind::Integer if self.hi[i] > self.lo[i] => {
                    (self.hi[i] - self.lo[i] + 1.0) / (p.span() + 1.0)
                }
                Kind::Integer => 0.0,
                _ => (self.hi[i] - self.lo[i]) / p.span(),
            };
            if w > best.1 {
                best = (i, w);
            }
        }
        best
    }

    fn centre_params(&self, s: &Shader) -> Vec<f64> {
        s.params
            .iter()
            .enumerate()
            .map(|(i, p)| match p.kind {
                Kind::Integer => ((self.lo[i] + self.hi[i]) / 2.0).floor(),
                _ => (self.lo[i] + self.hi[i]) / 2.0,
            })
            .collect()
    }

    fn halves(&self, dim: usize, kind: Kind) -> (Cell, Cell) {
        let (mut a, mut b) = (self.clone(), self.clone());
        a.parent = self.centre;
        b.parent = self.centre;
        match kind {
            Kind::Integer => {
                let m = ((self.lo[dim] + self.hi[dim]) / 2.0).floor();
                a.hi[dim] = m;
                b.lo[dim] = m + 1.0;
            }
            _ => {
                let m = (self.lo[dim] + self.hi[dim]) / 2.0;
                a.hi[dim] = m;
                b.lo[dim] = m;
            }
        }
        (a, b)
    }
}

/// A cell waiting to be split, ordered by priority then age.
struct Pending {
    priority: f64,
    order: usize,
    cell: Cell,
}

impl PartialEq for Pending {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == std::cmp::Ordering::Equal
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Pending {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.priority
            .total_cmp(&o.priority)
            .then(o.order.cmp(&self.order))
    }
}

/// Renders `params` of `s` at `size`² and describes it.
pub fn describe(s: &Shader, params: &[f64], size: usize) -> Structure {
    Structure::of_field(&s.render_field(params, size, size, size), size, size)
}

/// The samples of one shader by adaptive subdivision; `tick` is called per
/// rendered sample.
pub fn sample_shader(
    s: &Shader,
    size: usize,
    budget: usize,
    tick: &(dyn Fn() + Sync),
) -> Vec<Sample> {
    let root = Cell {
        lo: s.params.iter().map(|p| p.min).collect(),
        hi: s
            .params
            .iter()
            .map(|p| match p.kind {
                // The periodic end is the start again: stop short of it.
                Kind::Periodic => p.max - p.span() / 64.0,
                _ => p.max,
            })
            .collect(),
        centre: 0,
        parent: 0,
    };
    let first = root.centre_params(s);
    let mut params = vec![first.clone()];
    let mut structures = vec![describe(s, &first, size)];
    tick();
    let mut heap = BinaryHeap::new();
    let mut order = 0;
    heap.push(Pending {
        priority: 1.0,
        order,
        cell: root,
    });
    while params.len() < budget && !heap.is_empty() {
        // The batch's halves, then their centres rendered in parallel.
        let mut halves = Vec::new();
        while halves.len() < 2 * BATCH {
            let Some(p) = heap.pop() else { break };
            let (dim, width) = p.cell.widest(s);
            if width == 0.0 {
                continue;
            }
            let (a, b) = p.cell.halves(dim, s.params[dim].kind);
            halves.push(a);
            halves.push(b);
        }
        if halves.is_empty() {
            break;
        }
        let room = budget - params.len();
        let mut fresh = Vec::new();
        for h in &mut halves {
            let c = h.centre_params(s);
            if let Some(i) = params.iter().position(|q| q == &c) {
                h.centre = i;
            } else if let Some(i) = fresh.iter().position(|q| q == &c) {
                h.centre = params.len() + i;
            } else if fresh.len() < room {
                h.centre = params.len() + fresh.len();
                fresh.push(c);
            } else {
                // Over budget: this half is not sampled.
                h.centre = usize::MAX;
            }
        }
        let described: Vec<Structure> = fresh
            .par_iter()
            .map(|c| {
                let d = describe(s, c, size);
                tick();
                d
            })
            .collect();
        params.extend(fresh);
        structures.extend(described);
        for h in halves {
            if h.centre == usize::MAX {
                continue;
            }
            let d = structures[h.centre].distance(&structures[h.parent]);
            let (_, width) = h.widest(s);
            order += 1;
            heap.push(Pending {
                priority: (d + 0.05) * width,
                order,
                cell: h,
            });
        }
    }
    let admissibility = admissibility(s, &params, &structures);
    params
        .into_iter()
        .zip(structures)
        .zip(admissibility)
        .map(|((params, structure), admissibility)| Sample {
            params,
            structure,
            admissibility,
        })
        .collect()
}

/// Euclidean distance in the unit parameter box (periodic parameters the
/// short way round).
pub fn unit_distance(s: &Shader, a: &[f64], b: &[f64]) -> f64 {
    s.params
        .iter()
        .zip(a.iter().zip(b))
        .map(|(p, (&x, &y))| p.distance(x, y).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// A(x) of every sample over its nearest catalogue neighbours (§3.2.1).
fn admissibility(s: &Shader, params: &[Vec<f64>], structures: &[Structure]) -> Vec<f64> {
    (0..params.len())
        .into_par_iter()
        .map(|i| {
            let mut near: Vec<(f64, usize)> = (0..params.len())
                .filter(|&j| j != i)
                .map(|j| (unit_distance(s, &params[i], &params[j]), j))
                .filter(|(d, _)| *d > 0.0)
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            near.truncate(ADMISSIBILITY_NEIGHBOURS);
            if near.is_empty() {
                return 0.0;
            }
            near.iter()
                .map(|&(d, j)| (1.0 - structures[i].distance(&structures[j])) / d)
                .sum::<f64>()
                / near.len() as f64
        })
        .collect()
}

impl Catalogue {
    /// Builds the catalogue; `tick` is called per rendered sample.
    pub fn build(settings: &BuildSettings, tick: &(dyn Fn() + Sync)) -> Result<Self> {
        settings.validate()?;
        let shaders = selected(settings.shaders.as_deref())?;
        let mut out = Vec::new();
        for s in shaders {
            let t = std::time::Instant::now();
            let samples = sample_shader(s, settings.size, settings.samples, tick);
            tracing::info!(
                shader = s.name,
                samples = samples.len(),
                seconds = t.elapsed().as_secs_f64(),
                "shader catalogued"
            );
            out.push(ShaderSamples {
                shader: s.name.to_string(),
                signature: signature(s),
                samples,
            });
        }
        Ok(Self {
            version: VERSION,
            size: settings.size,
            shaders: out,
        })
    }

    /// Writes the catalogue as JSON, atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let json = serde_json::to_vec(self)?;
        imaging::save_bytes(path, &json)
    }

    /// Reads and checks a catalogue written by [`Catalogue::save`].
    pub fn load(path: &Path) -> Result<Self> {
        let rebuild = format!(
            "rebuild it with: texsyn match catalogue -o {}",
            path.display()
        );
        let bytes =
            imaging::read_regular(path, MAX_CATALOGUE_BYTES, "catalogue").with_context(|| {
                format!(
                    "build a catalogue with: texsyn match catalogue -o {}",
                    path.display()
                )
            })?;
        let cat: Catalogue = serde_json::from_slice(&bytes).map_err(|e| {
            anyhow::anyhow!(
                "{} is not a texsyn catalogue ({e}); {rebuild}",
                path.display()
            )
        })?;
        if cat.version != VERSION {
            bail!(
                "catalogue {} has version {}, this texsyn reads version {VERSION}; {rebuild}",
                path.display(),
                cat.version
            );
        }
        ensure!(
            (32..=512).contains(&cat.size) && !cat.shaders.is_empty(),
            "catalogue {} is empty or has a bad size; {rebuild}",
            path.display()
        );
        // Every descriptor must have the shape this texsyn computes at the
        // catalogue's size: a short one would index past its end.
        let reference = Structure::of_values(&vec![0.0; cat.size * cat.size], cat.size, cat.size);
        for sc in &cat.shaders {
            let s = super::shaders::by_name(&sc.shader).with_context(|| {
                format!(
                    "catalogue {} has shader '{}', which this texsyn lacks; {rebuild}",
                    path.display(),
                    sc.shader
                )
            })?;
            ensure!(
                sc.signature == signature(s),
                "catalogue {} was built for other parameters of shader '{}'; {rebuild}",
                path.display(),
                sc.shader
            );
            let shape = |d: &Structure| {
                (
                    d.spectrum.len(),
                    d.bands.iter().map(Vec::len).collect::<Vec<_>>(),
                    d.quantiles.len(),
                )
            };
            ensure!(
                !sc.samples.is_empty()
                    && sc.samples.iter().all(|x| x.params.len() == s.params.len())
                    && sc
                        .samples
                        .iter()
                        .all(|x| shape(&x.structure) == shape(&reference)),
                "catalogue {} has malformed samples of shader '{}'; {rebuild}",
                path.display(),
                sc.shader
            );
        }
        Ok(cat)
    }

    /// The samples of the shader called `name`.
    pub fn of(&self, name: &str) -> Option<&ShaderSamples> {
        self.shaders.iter().find(|s| s.shader == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::shaders::by_name;
    use std::collections::HashSet;

    #[test]
    fn subdivision_is_deterministic_and_covers_integer_values() {
        let s = by_name("bricks").unwrap();
        let [one, two] = crate::procedural::one_and_two_threads();
        let a = one.install(|| sample_shader(s, 48, 40, &|| {}));
        let b = two.install(|| sample_shader(s, 48, 40, &|| {}));
        assert_eq!(a, b);
        assert_eq!(a.len(), 40);
        let rows: HashSet<i64> = a.iter().map(|x| x.params[0] as i64).collect();
        assert!(rows.len() >= 3, "{rows:?}");
        for x in &a {
            assert_eq!(x.params[0].fract(), 0.0);
            assert!(x.admissibility.is_finite() && x.admissibility > 0.0);
        }
    }
}
