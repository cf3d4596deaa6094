//! texsyn's search engine: neighbourhood vector layout, SIMD distance kernels and
//! exact exhaustive search (Stahlhut §6–§8), plus the gRPC worker that serves it
//! to a master. The master's local search calls the same [`Engine`] in-process.

pub mod bench;
pub mod error;
pub mod kernel;
pub mod layout;
pub mod lbg;
pub mod search;
pub mod service;

pub use error::{EngineError, Result};
pub use kernel::{distance, Kernel, Params};
pub use layout::{
    Geometry, Layout, Metric, OwnedPlane, Plane, QueryBatch, Sample, VectorSpace, Weights,
};
pub use lbg::{Codebook, LbgConfig, LbgStats};
pub use search::{merge_best, merge_topk, Engine, Hit};
