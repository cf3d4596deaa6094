//! The texsyn cluster protocol: tonic/prost code generated from
//! `proto/texsyn.proto`, the conversions between it and the engine's types
//! ([`wire`]), the shared-token handling ([`auth`]) and worker addresses with
//! client TLS ([`tls`]). Master and worker both
//! speak through this crate only.

pub mod auth;
pub mod cli;
pub mod tls;
pub mod wire;

/// Protocol version spoken by this build; master and worker refuse to talk across versions.
pub const PROTOCOL_VERSION: u32 = 3;

#[allow(clippy::all, missing_docs)]
pub mod v1 {
    tonic::include_proto!("texsyn.v1");
}

pub use v1::*;
