//! Procedural texture matching and transformation (Bourque–Dudek;
//! ARCHITECTURE §12): find the shader and parameters that reproduce a
//! photographed texture, and animate between textures through parameter
//! space.
//!
//! - [`shaders`]: the shader library and its declared parameters (§3.1).
//! - [`descriptor`]: the colour-free structure descriptor the catalogue
//!   stores (§3.2.1, §3.3).
//! - [`catalogue`]: adaptive subdivision of each parameter domain (§3.2.1).
//! - [`matching`]: global search by admissibility, Nelder–Mead refinement
//!   (§3.2).
//! - [`transform`]: paths within a shader, key-textures and jump points
//!   between shaders (§4).
//!
//! The similarity measures S_F, S_L and the colour term are those of
//! [`crate::compare`], shared with `texsyn compare`.

pub mod catalogue;
pub mod descriptor;
pub mod matching;
pub mod shaders;
pub mod transform;

pub use catalogue::{BuildSettings, Catalogue};
pub use matching::{match_texture, MatchResult, MatchSettings, Pattern};
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
