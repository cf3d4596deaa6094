//! What `texsyn match` and `texsyn match transform` do, as validated
//! configurations: every flag, input and output is checked here, before
//! any work is done or any file is written.

use std::path::{Path, PathBuf};

use anyhow::{ensure, Result};

use super::catalogue::Catalogue;
use super::search::{match_texture, MatchResult, MatchSettings};
use super::transform::TransformSettings;
use crate::budget::Budget;
use crate::imaging::{self, animation, paths};

/// The message for a missing `--catalogue`.
pub const NO_CATALOGUE: &str = "no --catalogue given; build one once with: texsyn match catalogue -o shaders.cat, then pass --catalogue shaders.cat";

/// Matching one target (Bourque–Dudek §3.2): the render and the parameters.
#[derive(Clone, Debug)]
pub struct MatchConfig {
    pub target: PathBuf,
    /// The catalogue file (empty: none given, refused).
    pub catalogue: PathBuf,
    /// The matched pattern rendered here.
    pub output: Option<PathBuf>,
    /// The match as JSON here (else on stdout).
    pub params: Option<PathBuf>,
    /// Render size (default: the target's).
    pub size: Option<(usize, usize)>,
    pub search: MatchSettings,
}

impl MatchConfig {
    /// Checks the settings and paths: outputs writable, distinct and not an
    /// input; a given render size fits the output's format.
    pub fn validate(&self) -> Result<()> {
        self.search.validate()?;
        ensure!(!self.catalogue.as_os_str().is_empty(), NO_CATALOGUE);
        let mut outputs: Vec<(&str, &Path)> = Vec::new();
        if let Some(o) = &self.output {
            imaging::check_writable(o)?;
            if let Some((w, h)) = self.size {
                imaging::check_output_size(o, w, h)?;
            }
            outputs.push(("-o", o));
        }
        if let Some(p) = &self.params {
            imaging::check_writable_any(p)?;
            outputs.push(("--params", p));
        }
        let inputs = [
            ("target", self.target.as_path()),
            ("--catalogue", &self.catalogue),
        ];
        paths::check_files(&outputs, &inputs, None)
    }

    /// Loads the target and the catalogue, matches, writes the render and
    /// the JSON; the JSON comes back when no `--params` file is given.
    pub fn run(&self) -> Result<(MatchResult, Option<String>)> {
        let target = imaging::load_color(&self.target)?;
        let (w, h) = self.size.unwrap_or((target.width, target.height));
        if let Some(o) = &self.output {
            imaging::check_output_size(o, w, h)?;
        }
        let cat = Catalogue::load(&self.catalogue)?;
        let m = match_texture(&target, &cat, &self.search)?;
        let json = serde_json::to_string_pretty(&m.to_json())?;
        if let Some(o) = &self.output {
            imaging::save_color(o, &m.pattern.render(w, h))?;
        }
        match &self.params {
            Some(p) => {
                imaging::save_bytes(p, json.as_bytes())?;
                Ok((m, None))
            }
            None => Ok((m, Some(json))),
        }
    }
}

/// Names of a transformation's files in its output directory.
pub fn frame_name(i: usize) -> String {
    format!("frame_{i:04}.png")
}
pub const GIF: &str = "transform.gif";
pub const WEBP: &str = "transform.webp";
pub const REPORT: &str = "transform.json";

/// Bytes per frame pixel at the peak of writing one frame: the RGB frame,
/// the shader's field, the GIF's RGBA copy and quantiser, the WebP still.
const PEAK_BYTES_PER_PIXEL: u64 = 32;

/// A transformation written as frames and animations (Bourque–Dudek §4).
#[derive(Clone, Debug)]
pub struct TransformConfig {
    /// The first texture: an image (matched) or a pattern JSON.
    pub a: PathBuf,
    /// The last texture, likewise.
    pub b: PathBuf,
    /// Key-textures passed through, in order.
    pub keys: Vec<PathBuf>,
    /// The catalogue file (empty: none given, refused).
    pub catalogue: PathBuf,
    /// The output directory, replaced as a whole.
    pub output: PathBuf,
    pub frames: usize,
    /// Frame size.
    pub size: (usize, usize),
    /// Milliseconds between animation frames; 0: no GIF and no WebP.
    pub delay: u32,
    pub path: TransformSettings,
    pub search: MatchSettings,
    pub budget: Budget,
}

impl TransformConfig {
    /// Every input with its flag.
    pub fn inputs(&self) -> Vec<(&str, &Path)> {
        let mut inputs: Vec<(&str, &Path)> = vec![("A", &self.a), ("B", &self.b)];
        inputs.extend(self.keys.iter().map(|k| ("--key", k.as_path())));
        inputs.push(("--catalogue", &self.catalogue));
        inputs
    }

    /// The stops in order: A, the keys, B.
    pub fn stops(&self) -> Vec<&Path> {
        let mut stops = vec![self.a.as_path()];
        stops.extend(self.keys.iter().map(PathBuf::as_path));
        stops.push(&self.b);
        stops
    }

    /// The peak memory of writing the frames: one frame at a time.
    pub fn peak_bytes(&self) -> u64 {
        (self.size.0 as u64 * self.size.1 as u64).saturating_mul(PEAK_BYTES_PER_PIXEL)
    }

    /// Checks every flag, input and the output directory before any work.
    pub fn validate(&self) -> Result<()> {
        ensure!(
            (2..=10_000).contains(&self.frames),
            "--frames {} must be in 2..=10000",
            self.frames
        );
        let (w, h) = self.size;
        imaging::check_size(w, h, "a frame (--size)")?;
        if self.delay > 0 {
            animation::check_animation(w, h, self.delay)?;
        }
        self.path.validate()?;
        self.search.validate()?;
        ensure!(!self.catalogue.as_os_str().is_empty(), NO_CATALOGUE);
        for (flag, p) in self.inputs() {
            ensure!(
                p.is_file(),
                "the {flag} {} does not exist or is not a file",
                p.display()
            );
        }
        imaging::check_output_dir(&self.output, &self.inputs())?;
        let parent = match self.output.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        ensure!(
            parent.is_dir(),
            "the directory {} of -o {} does not exist; create it first",
            parent.display(),
            self.output.display()
        );
        self.budget.check(
            &format!("writing {w}×{h} frames"),
            self.peak_bytes(),
            "use a smaller --size",
        )
    }
}
