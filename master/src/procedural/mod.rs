//! Procedural texture matching and transformation (Bourque–Dudek;
//! ARCHITECTURE §12): find the shader and parameters that reproduce a
//! photographed texture, and animate between textures through parameter
//! space.
//!
//! - [`shaders`]: the shader library and its declared parameters (§3.1).
//! - [`descriptor`]: the colour-free structure descriptor the catalogue
//!   stores (§3.2.1, §3.3).
//! - [`catalogue`]: the samples of every shader, saved and checked;
//!   [`sampling`]: adaptive subdivision of each parameter domain (§3.2.1).
//! - [`pattern`]: a shader with parameters and colours, rendered (§3.1).
//! - [`periodicity`]: the target's periods, read from its autocorrelation:
//!   the seeds of counts and angles and the structure term (§3.2.1, §3.3).
//! - [`pieces`]: how the tones break into pieces: scattered features
//!   against noise, in the structure term (§3.3).
//! - [`arrangement`]: lattice, parallel, scattered or unordered, from the
//!   periods and the spectrum: the shaders the global search tries (§3.3).
//! - [`colour`]: the closed-form two-colour fit (§3.2).
//! - [`objective`]: what the local search minimises (§3.2.2).
//! - [`search`]: global search by admissibility (§3.2.1), then [`local`]:
//!   Nelder–Mead refinement, sweeps and whole-number steps (§3.2.2).
//! - [`recovery`]: synthetic targets recovered, for tests and benches;
//!   [`labels`]: photos labelled with family and count, and the check.
//! - [`transform`]: paths within a shader, key-textures and jump points
//!   between shaders (§4); [`jumps`]: the jump points (§4.3).
//! - [`config`]: the commands' validated configurations; [`animate`]: a
//!   transformation's stops read and its frames written one at a time.
//!
//! The similarity measures S_F, S_L and the colour term are those of
//! [`crate::compare`], shared with `texsyn compare`.

pub mod animate;
pub mod arrangement;
pub mod catalogue;
pub mod colour;
pub mod config;
pub mod descriptor;
pub mod jumps;
pub mod labels;
pub mod local;
pub mod objective;
pub mod pattern;
pub mod periodicity;
pub mod pieces;
pub mod recovery;
pub mod sampling;
pub mod search;
pub mod shaders;
pub mod transform;

pub use catalogue::{BuildSettings, Catalogue};
pub use config::{MatchConfig, TransformConfig};
pub use objective::analysis_image;
pub use pattern::Pattern;
pub use recovery::{draw, recovered, recovery_trials, worst_error, Trial};
pub use search::{match_texture, Candidate, MatchResult, MatchSettings};
pub use shaders::{Kind, ParamSpec, Shader, LIBRARY};

/// A pool of one thread and one of two, for tests that a result does not
/// depend on the thread count.
#[cfg(test)]
pub(crate) fn one_and_two_threads() -> [rayon::ThreadPool; 2] {
    [1, 2].map(|n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .expect("a thread pool")
    })
}
