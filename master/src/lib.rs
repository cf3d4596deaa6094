//! texsyn: exact texture synthesis with the nearest-neighbour search on this
//! machine or on a cluster of workers (ARCHITECTURE §1–§2).
//!
//! - [`block`]: Stahlhut's multi-scale block method (plan → per level →
//!   finish), with its canvas, block queue, neighbourhoods, pyramid and colour
//!   rebuild.
//! - [`search`] and [`cluster`]: the search backends a method calls, all behind
//!   [`search::SearchBackend`]; [`launch`] starts or finds the workers.
//! - [`imaging`] (images in and out, atomic writes) and [`ycbcr`] (the one
//!   BT.601 conversion): shared by every method.
//! - [`cli`]: the command line; [`cleanup`]: the temporaries removed on
//!   SIGINT/SIGTERM.
//!
//! A new synthesis method goes into its own module beside [`block`] (for the
//! coming ones: `tiles`, `parallel`, `procedural`), reusing `imaging`, `ycbcr`,
//! the search backends and, where it fits, `block::pyramid`.

pub mod block;
pub mod budget;
pub mod cleanup;
pub mod cli;
pub mod cluster;
pub mod compare;
pub mod filters;
pub mod imaging;
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
};
