//! texsyn: exact multi-scale block texture synthesis after Stahlhut, with the
//! nearest-neighbour search on this machine or on a cluster of workers.
//!
//! Map (ARCHITECTURE §3):
//! - [`block`]: Stahlhut's block method (plan → per level → finish), with its
//!   canvas, block queue, neighbourhoods, pyramid and colour rebuild.
//! - [`search`], [`lbg`], [`cluster`]: the search backends a method calls.
//! - [`imaging`] (images in and out, atomic writes) and [`ycbcr`] (the one
//!   BT.601 conversion): shared by every method.
//! - [`cli`]: the command line.
//!
//! A new synthesis method goes into its own module beside [`block`] (for the
//! coming ones: `tiles`, `parallel`, `procedural`), reusing `imaging`, `ycbcr`,
//! the search backends and, where it fits, `block::pyramid`.

pub mod benchmark;
pub mod block;
pub mod cli;
pub mod cluster;
pub mod imaging;
pub mod lbg;
pub mod search;
pub mod ycbcr;

pub use block::{colour, pyramid};
pub use block::{synthesize, Config, Mode, Output, Position, Report, SynthMethod};

/// The block method's API under its former path `texsyn::synth`, kept so
/// existing callers (`synth::Silent`, `synth::Progress`, ...) need no change.
pub mod synth {
    pub use crate::block::{
        resolve_levels, synthesize, Config, LevelReport, Mode, Output, Position, Progress, Report,
        Silent, SynthMethod, MAX_CANVAS_PIXELS,
    };
}
