//! The multi-process integration tests in one binary: real `texsyn-worker`
//! processes over gRPC on 127.0.0.x, TLS, ssh launch, network partitions,
//! the deployment files and containers.

mod harness;

mod cluster;
mod containers;
mod deploy;
mod hardening;
mod partition;
mod ssh;
mod tls;
