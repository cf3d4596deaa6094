//! The engine's integration tests in one binary: exact search against a
//! scalar reference, pruning, storage and LBG.

mod engine;
mod kdtree;
mod lbg;
mod pruning;
mod storage;
