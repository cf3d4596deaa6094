//! texsyn's gRPC worker: serves the search engine of `texsyn-engine` to a
//! master over the `texsyn.v1.Worker` protocol of `texsyn-proto`
//! (ARCHITECTURE §4).

pub mod service;
