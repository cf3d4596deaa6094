//! The catalogue (Bourque–Dudek §3.2.1): each shader's parameter domain
//! sampled by adaptive subdivision, every sample rendered once and kept as
//! its structure descriptor and admissibility. Built once, saved as JSON,
//! rebuilt when the shader library changes. The samples come from
//! [`super::sampling`].

use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};

use super::descriptor::Structure;
pub use super::sampling::sample_shader;
use super::shaders::{Shader, LIBRARY};
use crate::imaging;
use crate::progress::Progress;

/// The file format's version; a catalogue of another version is rebuilt.
pub const VERSION: u32 = 1;
/// Largest catalogue file read (the default catalogue is a few MiB).
const MAX_CATALOGUE_BYTES: u64 = 256 << 20;
/// Render side of the catalogue's samples (and of the matching analysis).
pub const DEFAULT_SIZE: usize = 128;
/// Samples per shader (the paper's catalogues held about 200).
pub const DEFAULT_SAMPLES: usize = 200;

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

/// Renders `params` of `s` at `size`² and describes it.
pub fn describe(s: &Shader, params: &[f64], size: usize) -> Structure {
    Structure::of_field(&s.render_field(params, size, size, size), size, size)
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

impl Catalogue {
    /// Builds the catalogue; `progress` is one stage of a step per sample.
    pub fn build(settings: &BuildSettings, progress: &dyn Progress) -> Result<Self> {
        settings.validate()?;
        let shaders = selected(settings.shaders.as_deref())?;
        progress.start(
            "catalogue",
            (shaders.len() * settings.samples) as u64,
            "samples",
        );
        let mut out = Vec::new();
        for s in shaders {
            let t = std::time::Instant::now();
            let samples = sample_shader(s, settings.size, settings.samples, progress);
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
        progress.finish();
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

    /// Its shaders and samples in a few words.
    pub fn summary(&self) -> String {
        let samples: usize = self.shaders.iter().map(|s| s.samples.len()).sum();
        let n = self.shaders.len();
        format!("{n} shaders, {samples} samples at {}²", self.size)
    }

    /// The samples of the shader called `name`.
    pub fn of(&self, name: &str) -> Option<&ShaderSamples> {
        self.shaders.iter().find(|s| s.shader == name)
    }
}
