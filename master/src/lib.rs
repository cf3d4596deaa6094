//! texsyn: exact texture synthesis with the nearest-neighbour search on this
//! machine or on a cluster of workers (ARCHITECTURE §1–§2).
//!
//! Methods, siblings that never import each other:
//! - [`block`]: Stahlhut's multi-scale block method;
//! - [`tiles`]: Somol–Haindl tile sets and ω-tiles;
//! - [`parallel`]: synthesis on exemplar coordinates, morphs and solids
//!   (Manke–Wünsche);
//! - [`procedural`]: procedural matching and transformation (Bourque–Dudek).
//!
//! The shared layer under them: [`pyramid`], [`filters`], [`seams`],
//! [`imaging`] (images, colour conversion, atomic file and directory
//! outputs, path checks), [`search`] (every method's search, opened by
//! [`search::open`]; [`cluster`] and [`launch`] behind it), [`budget`] (the
//! memory budget), [`progress`] (how methods report progress), [`compare`]
//! (the measures) and [`cleanup`] (temporaries removed on SIGINT/SIGTERM).
//! [`cli`] only parses, builds validated configs, calls the library and
//! reports.

pub mod block;
pub mod budget;
pub mod cleanup;
pub mod cli;
pub mod cluster;
pub mod compare;
pub mod filters;
pub mod imaging;
pub mod lattice;
pub mod launch;
pub mod parallel;
pub mod procedural;
pub mod progress;
pub mod pyramid;
pub mod seams;
pub mod search;
pub mod tiles;

pub use block::{
    synthesize, Config, FillSource, Mode, Output, Position, Report, Stitch, SynthMethod,
    PATH_GROWTH_NEIGHBOURHOOD,
};
