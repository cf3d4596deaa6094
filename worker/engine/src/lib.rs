//! texsyn's search engine: the neighbourhood vector layout, the SIMD distance
//! kernels and the exact exhaustive search (Stahlhut §6–§8), LBG codebooks
//! (Stahlhut §8), calibration and the merge of partial answers.
//!
//! This crate has no async and no network code. The master's in-process search
//! and the worker's gRPC service both call the same [`Engine`]; nothing else in
//! texsyn searches. See docs/ARCHITECTURE.md for where it sits.

pub mod batch;
pub mod budget;
pub mod calibrate;
pub mod error;
pub mod kdtree;
pub mod kernel;
pub mod layout;
pub mod lbg;
pub mod level;
pub mod link;
pub mod merge;
pub mod plane;
pub mod positions;
pub mod profile;
pub mod search;
pub mod space;
pub mod spin;
mod window;

pub use batch::QueryBatch;
pub use calibrate::{calibrate, Calibration, CalibrationSize};
pub use error::{EngineError, Result};
pub use kernel::{distance, Kernel, Params, PruneStats};
pub use layout::{Geometry, Layout, Metric, Weights};
pub use lbg::{Codebook, LbgConfig, LbgStats};
pub use level::{OwnedLevel, Scorer};
pub use link::Link;
pub use merge::{
    check_linked_part, check_part, merge_answers, merge_best, merge_topk, with_bounds, Hit, Slack,
};
pub use plane::{OwnedPlane, Plane, Sample};
pub use positions::Positions;
pub use profile::Profile;
pub use search::Engine;
pub use space::{Storage, VectorSpace};
