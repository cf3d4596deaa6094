//! Helpers for the master's side of the protocol: the token interceptor,
//! engine ↔ protocol conversions and reading a started worker's port.

use std::net::SocketAddr;

use anyhow::{bail, Context};
use texsyn_proto::v1 as proto;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::{Request, Status};

use crate::kernel::Params;
use crate::layout::{Geometry, Metric, Plane};
use crate::search::Hit;

/// Client interceptor adding `authorization: Bearer <token>` to every call
/// (nothing when there is no token):
/// `WorkerClient::with_interceptor(channel, BearerAuth::new(token)?)`.
#[derive(Clone, Default)]
pub struct BearerAuth {
    value: Option<MetadataValue<Ascii>>,
}

impl BearerAuth {
    pub fn new(token: Option<&str>) -> anyhow::Result<Self> {
        let value = token
            .map(|t| {
                format!("Bearer {t}")
                    .parse::<MetadataValue<Ascii>>()
                    .context("the token must be printable ASCII")
            })
            .transpose()?;
        Ok(Self { value })
    }
}

impl std::fmt::Debug for BearerAuth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BearerAuth")
            .field("token", &self.value.as_ref().map(|_| "<redacted>"))
            .finish()
    }
}

impl Interceptor for BearerAuth {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.value {
            request.metadata_mut().insert("authorization", v.clone());
        }
        Ok(request)
    }
}

/// Reads the address from a worker's `listening on ADDR` stdout line.
pub fn parse_listening_line(line: &str) -> Option<SocketAddr> {
    line.trim().strip_prefix("listening on ")?.parse().ok()
}

/// A level plane as sent in `LoadLevel` (an all-defined mask is sent empty).
pub fn plane_to_proto(p: &Plane) -> proto::Plane {
    let defined = match p.defined {
        Some(d) if d.contains(&0) => d.to_vec(),
        _ => Vec::new(),
    };
    proto::Plane {
        width: p.width as u32,
        height: p.height as u32,
        pixels: p.pixels.to_vec(),
        defined,
    }
}

pub fn geometry_to_proto(g: &Geometry, params: &Params) -> proto::Geometry {
    proto::Geometry {
        neighbourhood: g.n as u32,
        parent_window: g.m as u32,
        weight_hi: params.weights.hi,
        weight_lo: params.weights.lo,
        metric: match params.metric {
            Metric::L1 => proto::Metric::L1,
            Metric::L2 => proto::Metric::L2,
        } as i32,
    }
}

pub fn hit_from_proto(h: &proto::Hit) -> Hit {
    Hit {
        index: h.index,
        dist: h.distance,
    }
}

/// The best-1 hits of a result to a batch of `count` queries, checked for shape
/// (a worker with an empty range answers [`Hit::NONE`], which `merge_best` ignores).
pub fn best_hits(result: &proto::SearchResult, count: usize) -> anyhow::Result<Vec<Hit>> {
    if result.per_query != 1 || result.hits.len() != count {
        bail!(
            "malformed best-1 answer: {} hits with per_query {} for {count} queries",
            result.hits.len(),
            result.per_query
        );
    }
    Ok(result.hits.iter().map(hit_from_proto).collect())
}

/// The top-k lists of a result to a batch of `count` queries, checked for shape.
pub fn topk_hits(result: &proto::SearchResult, count: usize) -> anyhow::Result<Vec<Vec<Hit>>> {
    let per = result.per_query as usize;
    if per.checked_mul(count) != Some(result.hits.len()) {
        bail!(
            "malformed top-k answer: {} hits with per_query {per} for {count} queries",
            result.hits.len()
        );
    }
    if per == 0 {
        return Ok(vec![Vec::new(); count]);
    }
    Ok(result
        .hits
        .chunks_exact(per)
        .map(|c| c.iter().map(hit_from_proto).collect())
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listening_line_round_trips() {
        let a: SocketAddr = "127.0.0.1:40123".parse().unwrap();
        assert_eq!(
            parse_listening_line(&super::super::listening_line(a)),
            Some(a)
        );
        assert_eq!(
            parse_listening_line("listening on [::1]:7\n"),
            "[::1]:7".parse().ok()
        );
        assert_eq!(parse_listening_line("hello"), None);
    }

    #[test]
    fn result_shapes_are_checked() {
        let r = proto::SearchResult {
            batch_id: 0,
            hits: vec![
                proto::Hit {
                    index: 1,
                    distance: 2
                };
                4
            ],
            per_query: 2,
            seconds: 0.0,
        };
        assert_eq!(topk_hits(&r, 2).unwrap().len(), 2);
        assert!(topk_hits(&r, 3).is_err());
        assert!(best_hits(&r, 4).is_err());
    }
}
