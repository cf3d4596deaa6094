//! Validation of requests into engine types. Every check happens before
//! anything is allocated for the request; a bad field is INVALID_ARGUMENT with a
//! message that names it.

use texsyn_proto::v1 as proto;
use tonic::Status;

use crate::error::EngineError;
use crate::kernel::Params;
use crate::layout::{Geometry, Metric, Plane, Weights};

/// Longest accepted job id, in bytes.
pub const MAX_JOB_ID_LEN: usize = 128;
/// Most queries in one search batch.
pub const MAX_QUERIES: usize = 1 << 16;
/// Largest `top_k` of a search batch.
pub const MAX_TOP_K: usize = 1024;
/// Largest side of a level plane, in pixels.
pub(crate) const MAX_PLANE_SIDE: u32 = 1 << 16;

pub(crate) fn invalid(msg: impl Into<String>) -> Status {
    Status::invalid_argument(msg)
}

/// Maps an engine error: bad input is INVALID_ARGUMENT, a CPU without the
/// configured kernel is INTERNAL.
pub(crate) fn engine_status(e: EngineError) -> Status {
    match e {
        EngineError::Kernel(..) => Status::internal(e.to_string()),
        _ => Status::invalid_argument(e.to_string()),
    }
}

/// A job id is 1..=128 bytes of printable characters.
pub(crate) fn check_job_id(id: &str) -> Result<(), Status> {
    if id.is_empty() {
        return Err(invalid("job_id is empty; give every job a non-empty id"));
    }
    if id.len() > MAX_JOB_ID_LEN {
        return Err(invalid(format!(
            "job_id has {} bytes; at most {MAX_JOB_ID_LEN} are allowed",
            id.len()
        )));
    }
    if id.chars().any(char::is_control) {
        return Err(invalid("job_id contains control characters"));
    }
    Ok(())
}

/// An owned, validated level plane.
#[derive(Debug)]
pub(crate) struct OwnedPlane {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
    pub defined: Option<Vec<u8>>,
}

impl OwnedPlane {
    /// Takes the plane's buffers (no copy) after checking its size and lengths.
    pub(crate) fn from_proto(p: proto::Plane, what: &str) -> Result<Self, Status> {
        if p.width == 0 || p.height == 0 {
            return Err(invalid(format!(
                "{what} plane is {}×{} pixels; both sides must be ≥ 1",
                p.width, p.height
            )));
        }
        if p.width > MAX_PLANE_SIDE || p.height > MAX_PLANE_SIDE {
            return Err(invalid(format!(
                "{what} plane is {}×{} pixels; each side may be at most {MAX_PLANE_SIDE}",
                p.width, p.height
            )));
        }
        let (w, h) = (p.width as usize, p.height as usize);
        let n = w
            .checked_mul(h)
            .ok_or_else(|| invalid(format!("{what} plane size {w}×{h} overflows")))?;
        if p.pixels.len() != n {
            return Err(invalid(format!(
                "{what} plane has {} pixel bytes, expected {w}×{h} = {n}",
                p.pixels.len()
            )));
        }
        if !p.defined.is_empty() && p.defined.len() != n {
            return Err(invalid(format!(
                "{what} plane has {} defined-mask bytes, expected 0 (all defined) or {w}×{h} = {n}",
                p.defined.len()
            )));
        }
        let defined = (!p.defined.is_empty() && p.defined.contains(&0)).then_some(p.defined);
        Ok(Self {
            width: w,
            height: h,
            pixels: p.pixels,
            defined,
        })
    }

    pub(crate) fn view(&self) -> Plane<'_> {
        Plane {
            width: self.width,
            height: self.height,
            pixels: &self.pixels,
            defined: self.defined.as_deref(),
        }
    }

    pub(crate) fn bytes(&self) -> u64 {
        (self.pixels.len() + self.defined.as_ref().map_or(0, Vec::len)) as u64
    }
}

/// Geometry and comparison parameters of a level.
pub(crate) fn geometry_from_proto(
    g: Option<&proto::Geometry>,
) -> Result<(Geometry, Params), Status> {
    let g = g.ok_or_else(|| invalid("geometry is missing"))?;
    let geometry =
        Geometry::new(g.neighbourhood as usize, g.parent_window as usize).map_err(engine_status)?;
    let weights = Weights::new(g.weight_hi, g.weight_lo).map_err(engine_status)?;
    let metric = match proto::Metric::try_from(g.metric) {
        Ok(proto::Metric::L1) => Metric::L1,
        Ok(proto::Metric::L2) => Metric::L2,
        Err(_) => {
            return Err(invalid(format!(
                "unknown metric {}; use METRIC_L1 (0) or METRIC_L2 (1)",
                g.metric
            )))
        }
    };
    Ok((geometry, Params { metric, weights }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: u32, h: u32, px: usize, def: usize) -> proto::Plane {
        proto::Plane {
            width: w,
            height: h,
            pixels: vec![0; px],
            defined: vec![1; def],
        }
    }

    #[test]
    fn planes_are_checked() {
        assert!(OwnedPlane::from_proto(plane(4, 3, 12, 0), "s").is_ok());
        assert!(OwnedPlane::from_proto(plane(4, 3, 12, 12), "s").is_ok());
        for bad in [
            plane(0, 3, 0, 0),
            plane(4, 3, 11, 0),
            plane(4, 3, 12, 5),
            plane(u32::MAX, u32::MAX, 0, 0),
        ] {
            let e = OwnedPlane::from_proto(bad, "s").unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument);
        }
    }

    #[test]
    fn job_ids_are_checked() {
        assert!(check_job_id("job-1").is_ok());
        assert!(check_job_id("").is_err());
        assert!(check_job_id(&"x".repeat(129)).is_err());
        assert!(check_job_id("a\nb").is_err());
    }

    #[test]
    fn geometry_is_checked() {
        let g = |n, m, hi, lo, metric| proto::Geometry {
            neighbourhood: n,
            parent_window: m,
            weight_hi: hi,
            weight_lo: lo,
            metric,
        };
        assert!(geometry_from_proto(Some(&g(5, 3, 1, 1, 0))).is_ok());
        assert!(geometry_from_proto(None).is_err());
        assert!(geometry_from_proto(Some(&g(4, 3, 1, 1, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 2, 1, 1, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 3, 0, 0, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 3, 1, 1, 7))).is_err());
    }
}
