//! texsyn: exact multi-scale block texture synthesis after Stahlhut, with the
//! nearest-neighbour search on this machine or on a cluster of workers.

pub mod cli;
pub mod cluster;
pub mod colour;
pub mod imaging;
pub mod launch;
pub mod neighbourhood;
pub mod pyramid;
pub mod queue;
pub mod search;
pub mod synth;

pub use search::lbg;

pub use synth::{synthesize, Config, Mode, Output, Position, Report, SynthMethod};
