//! texsyn's gRPC worker: serves the search engine of `texsyn-engine` to a
//! master over the `texsyn.v1.Worker` protocol of `texsyn-proto`
//! (ARCHITECTURE §4).
//!
//! [`service`] is the gRPC server, [`process`] the process around it (runtime,
//! listening line, shutdown), [`cli`] the command line and [`health`] the
//! health-check client.

pub mod cli;
pub mod health;
pub mod process;
pub mod service;
