//! texsyn's integration tests in one binary (one link instead of one per
//! file): the library and the `texsyn` binary on real images. The
//! clean-up registry's test is its own binary, as it closes a registry
//! that is process-wide.

mod common;

mod cli;
mod depth;
mod lbg;
mod parallel;
mod procedural;
mod solid;
mod synthesis;
mod tiles;
