//! Conversions between the engine's types and the protocol's messages, both
//! ways, in one place (ARCHITECTURE §4.1). Everything that comes
//! off the wire is validated here before anything is allocated for it; a bad
//! field becomes INVALID_ARGUMENT with a message that names it.

use std::net::SocketAddr;

use anyhow::bail;
use texsyn_engine::{
    EngineError, Geometry, Hit, Metric, OwnedLevel, OwnedPlane, Params, Plane, PruneStats,
    QueryBatch, Sample, Weights,
};
use tonic::Status;

use crate::v1 as pb;

/// Longest accepted job id, in bytes.
pub const MAX_JOB_ID_LEN: usize = 128;
/// Most queries in one search batch.
pub const MAX_QUERIES: usize = 1 << 16;
/// Largest `top_k` of a search batch.
pub const MAX_TOP_K: usize = 1024;
/// Largest side of a level plane, in pixels.
pub const MAX_PLANE_SIDE: u32 = 1 << 16;

/// INVALID_ARGUMENT with `msg`.
pub fn invalid(msg: impl Into<String>) -> Status {
    Status::invalid_argument(msg)
}

/// Maps an engine error: bad input is INVALID_ARGUMENT, a CPU without the
/// configured kernel is INTERNAL.
pub fn engine_status(e: EngineError) -> Status {
    match e {
        EngineError::Kernel(..) => Status::internal(e.to_string()),
        _ => Status::invalid_argument(e.to_string()),
    }
}

/// A job id is 1..=128 bytes of printable characters.
pub fn check_job_id(id: &str) -> Result<(), Status> {
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

/// A level plane as sent in `LoadLevel` (an all-defined mask is sent empty).
impl From<&Plane<'_>> for pb::Plane {
    fn from(p: &Plane<'_>) -> Self {
        let defined = match p.defined {
            Some(d) if d.contains(&0) => d.to_vec(),
            _ => Vec::new(),
        };
        pb::Plane {
            width: p.width as u32,
            height: p.height as u32,
            pixels: p.pixels.to_vec(),
            defined,
        }
    }
}

/// Takes the plane's buffers (no copy) after checking its size and lengths.
/// An all-defined mask becomes `None`.
impl TryFrom<pb::Plane> for OwnedPlane {
    type Error = Status;

    fn try_from(p: pb::Plane) -> Result<Self, Status> {
        if p.width == 0 || p.height == 0 {
            return Err(invalid(format!(
                "plane is {}×{} pixels; both sides must be ≥ 1",
                p.width, p.height
            )));
        }
        if p.width > MAX_PLANE_SIDE || p.height > MAX_PLANE_SIDE {
            return Err(invalid(format!(
                "plane is {}×{} pixels; each side may be at most {MAX_PLANE_SIDE}",
                p.width, p.height
            )));
        }
        let (w, h) = (p.width as usize, p.height as usize);
        let n = w
            .checked_mul(h)
            .ok_or_else(|| invalid(format!("plane size {w}×{h} overflows")))?;
        if p.pixels.len() != n {
            return Err(invalid(format!(
                "plane has {} pixel bytes, expected {w}×{h} = {n}",
                p.pixels.len()
            )));
        }
        if !p.defined.is_empty() && p.defined.len() != n {
            return Err(invalid(format!(
                "plane has {} defined-mask bytes, expected 0 (all defined) or {w}×{h} = {n}",
                p.defined.len()
            )));
        }
        let defined = (!p.defined.is_empty() && p.defined.contains(&0)).then_some(p.defined);
        Ok(OwnedPlane {
            width: w,
            height: h,
            pixels: p.pixels,
            defined,
        })
    }
}

/// [`OwnedPlane::try_from`] with the plane's role (`sample`, `parent`) named in
/// the error.
pub fn plane_from_proto(p: pb::Plane, what: &str) -> Result<OwnedPlane, Status> {
    OwnedPlane::try_from(p).map_err(|s| invalid(format!("{what} {}", s.message())))
}

/// Geometry and comparison parameters of a level, as sent.
pub fn geometry_to_proto(g: &Geometry, params: &Params) -> pb::Geometry {
    pb::Geometry {
        neighbourhood: g.n as u32,
        parent_window: g.m as u32,
        weight_hi: params.weights.hi,
        weight_lo: params.weights.lo,
        metric: match params.metric {
            Metric::L1 => pb::Metric::L1,
            Metric::L2 => pb::Metric::L2,
        } as i32,
    }
}

/// Geometry and comparison parameters of a level, validated.
pub fn geometry_from_proto(g: Option<&pb::Geometry>) -> Result<(Geometry, Params), Status> {
    let g = g.ok_or_else(|| invalid("geometry is missing"))?;
    let geometry =
        Geometry::new(g.neighbourhood as usize, g.parent_window as usize).map_err(engine_status)?;
    let weights = Weights::new(g.weight_hi, g.weight_lo).map_err(engine_status)?;
    let metric = match pb::Metric::try_from(g.metric) {
        Ok(pb::Metric::L1) => Metric::L1,
        Ok(pb::Metric::L2) => Metric::L2,
        Err(_) => {
            return Err(invalid(format!(
                "unknown metric {}; use METRIC_L1 (0) or METRIC_L2 (1)",
                g.metric
            )))
        }
    };
    Ok((geometry, Params { metric, weights }))
}

/// The `LoadLevel` request of level `level` of job `job_id`: the geometry, the
/// comparison parameters and the sample planes (ARCHITECTURE §4.1).
pub fn load_level_request(
    job_id: &str,
    level: u32,
    geometry: &Geometry,
    params: &Params,
    sample: &Sample,
) -> pb::LoadLevelRequest {
    pb::LoadLevelRequest {
        job_id: job_id.to_string(),
        level,
        geometry: Some(geometry_to_proto(geometry, params)),
        sample: Some(pb::Plane::from(&sample.fine)),
        parent: sample.parent.as_ref().map(pb::Plane::from),
    }
}

/// A validated `LoadLevel` request: the job and the pieces of its
/// [`OwnedLevel`] (whose reference positions [`LevelLoad::locate`] computes).
#[derive(Debug)]
pub struct LevelLoad {
    pub job_id: String,
    pub level: u32,
    pub geometry: Geometry,
    pub params: Params,
    pub sample: OwnedPlane,
    /// Present exactly when the geometry has a parent window.
    pub parent: Option<OwnedPlane>,
}

/// Checks, in this order, the job id, the geometry, the sample and parent
/// planes, and that a parent plane is given exactly when the geometry has a
/// parent window.
impl TryFrom<pb::LoadLevelRequest> for LevelLoad {
    type Error = Status;

    fn try_from(r: pb::LoadLevelRequest) -> Result<Self, Status> {
        check_job_id(&r.job_id)?;
        let (geometry, params) = geometry_from_proto(r.geometry.as_ref())?;
        let sample = plane_from_proto(
            r.sample
                .ok_or_else(|| invalid("the sample plane is missing"))?,
            "sample",
        )?;
        let parent = r
            .parent
            .map(|p| plane_from_proto(p, "parent"))
            .transpose()?;
        match (geometry.m, &parent) {
            (0, Some(_)) => {
                return Err(invalid(
                    "a parent plane was given but the geometry has no parent window (parent_window = 0)",
                ))
            }
            (m, None) if m > 0 => {
                return Err(invalid(format!(
                    "the geometry has a {m}×{m} parent window but no parent plane was given"
                )))
            }
            _ => {}
        }
        Ok(Self {
            job_id: r.job_id,
            level: r.level,
            geometry,
            params,
            sample,
            parent,
        })
    }
}

impl LevelLoad {
    /// Bytes of the sample planes (pixels and defined-masks).
    pub fn plane_bytes(&self) -> u64 {
        self.sample.bytes() + self.parent.as_ref().map_or(0, OwnedPlane::bytes)
    }

    /// The level with its reference positions (the expensive part: run it off
    /// the I/O threads).
    pub fn locate(self) -> texsyn_engine::Result<OwnedLevel> {
        OwnedLevel::locate(
            self.level as usize,
            self.geometry,
            self.params,
            self.sample,
            self.parent,
        )
    }
}

impl From<pb::LoadLevelRequest> for pb::LoadLevelPart {
    /// A whole level in one message: the header with every byte of its planes.
    fn from(header: pb::LoadLevelRequest) -> Self {
        Self {
            header: Some(header),
            piece: None,
        }
    }
}

/// The `LoadLevel` stream of `level` (ARCHITECTURE §4.1): a header whose
/// planes carry their sizes only, then the planes' bytes in pieces of at most
/// `piece` bytes. Each piece is copied out of the level when the stream is
/// polled, so sending a level costs a piece of memory per worker, not a copy
/// of the level.
pub fn load_level_parts(
    job_id: &str,
    level: std::sync::Arc<OwnedLevel>,
    piece: usize,
) -> impl Iterator<Item = pb::LoadLevelPart> + Send + 'static {
    use pb::PlaneBuffer as B;
    let piece = piece.max(1);
    let size = |p: &OwnedPlane| pb::Plane {
        width: p.width as u32,
        height: p.height as u32,
        pixels: Vec::new(),
        defined: Vec::new(),
    };
    let header = pb::LoadLevelRequest {
        job_id: job_id.to_string(),
        level: level.level as u32,
        geometry: Some(geometry_to_proto(&level.geometry, &level.params)),
        sample: Some(size(&level.fine)),
        parent: level.parent.as_ref().map(size),
    };
    // (buffer, length) of every buffer that is sent; an all-defined mask is not.
    let sends_mask = |p: &OwnedPlane| p.defined.as_ref().is_some_and(|d| d.contains(&0));
    let mut buffers = vec![(B::SamplePixels, level.fine.pixels.len())];
    if sends_mask(&level.fine) {
        buffers.push((B::SampleDefined, level.fine.pixels.len()));
    }
    if let Some(p) = &level.parent {
        buffers.push((B::ParentPixels, p.pixels.len()));
        if sends_mask(p) {
            buffers.push((B::ParentDefined, p.pixels.len()));
        }
    }
    let pieces = buffers.into_iter().flat_map(move |(buffer, len)| {
        let level = level.clone();
        (0..len).step_by(piece).map(move |at| {
            let bytes = match buffer {
                B::SamplePixels => &level.fine.pixels[..],
                B::SampleDefined => level.fine.defined.as_deref().unwrap_or_default(),
                B::ParentPixels => level.parent.as_ref().map_or(&[][..], |p| &p.pixels[..]),
                B::ParentDefined => level
                    .parent
                    .as_ref()
                    .and_then(|p| p.defined.as_deref())
                    .unwrap_or_default(),
            };
            pb::LoadLevelPart {
                header: None,
                piece: Some(pb::PlanePiece {
                    buffer: buffer as i32,
                    data: bytes[at..(at + piece).min(len)].to_vec(),
                }),
            }
        })
    });
    std::iter::once(pb::LoadLevelPart::from(header)).chain(pieces)
}

/// A `LoadLevel` stream being received: the header, then each piece appended
/// to the buffer it names, never past the plane's size.
#[derive(Debug)]
pub struct LevelAssembly {
    header: pb::LoadLevelRequest,
}

impl LevelAssembly {
    /// Starts from the stream's first message, which must carry the header;
    /// checks the job id and the geometry and that the planes' sizes are sane.
    pub fn start(first: pb::LoadLevelPart) -> Result<Self, Status> {
        let header = first.header.ok_or_else(|| {
            invalid("the first LoadLevel message carries no header; send the job, level, geometry and plane sizes first")
        })?;
        check_job_id(&header.job_id)?;
        geometry_from_proto(header.geometry.as_ref())?;
        for (p, what) in [
            (header.sample.as_ref(), "sample"),
            (header.parent.as_ref(), "parent"),
        ] {
            if let Some(p) = p {
                if p.width == 0
                    || p.height == 0
                    || p.width > MAX_PLANE_SIDE
                    || p.height > MAX_PLANE_SIDE
                {
                    return Err(invalid(format!(
                        "{what} plane of {}×{} pixels; each side must be 1..={MAX_PLANE_SIDE}",
                        p.width, p.height
                    )));
                }
            }
        }
        // The parent is the sample one pyramid level down (each side halved,
        // rounded up); anything larger is not a parent and is refused before
        // it is received.
        if let (Some(s), Some(p)) = (header.sample.as_ref(), header.parent.as_ref()) {
            if p.width > s.width.div_ceil(2) || p.height > s.height.div_ceil(2) {
                return Err(invalid(format!(
                    "parent plane of {}×{} pixels for a {}×{} sample; a parent is the sample halved, at most {}×{}",
                    p.width,
                    p.height,
                    s.width,
                    s.height,
                    s.width.div_ceil(2),
                    s.height.div_ceil(2)
                )));
            }
        }
        let mut a = Self { header };
        if let Some(p) = first.piece {
            a.add(pb::LoadLevelPart {
                header: None,
                piece: Some(p),
            })?;
        }
        Ok(a)
    }

    /// The job the level is for.
    pub fn job_id(&self) -> &str {
        &self.header.job_id
    }

    /// Pixels of the sample and parent planes (without defined-masks).
    pub fn pixels(&self) -> u64 {
        let px = |p: Option<&pb::Plane>| p.map_or(0, |p| u64::from(p.width) * u64::from(p.height));
        px(self.header.sample.as_ref()) + px(self.header.parent.as_ref())
    }

    /// Width × height of the sample plane.
    pub fn sample_pixels(&self) -> u64 {
        self.header
            .sample
            .as_ref()
            .map_or(0, |p| u64::from(p.width) * u64::from(p.height))
    }

    /// Appends one later message's piece to its buffer.
    pub fn add(&mut self, part: pb::LoadLevelPart) -> Result<(), Status> {
        use pb::PlaneBuffer as B;
        if part.header.is_some() {
            return Err(invalid(
                "a LoadLevel stream carries its header in the first message only",
            ));
        }
        let piece = part
            .piece
            .ok_or_else(|| invalid("a LoadLevel message after the first carries no piece"))?;
        let buffer = B::try_from(piece.buffer).map_err(|_| {
            invalid(format!(
                "unknown plane buffer {} in a LoadLevel piece",
                piece.buffer
            ))
        })?;
        let (plane, what) = match buffer {
            B::SamplePixels | B::SampleDefined => (self.header.sample.as_mut(), "sample"),
            B::ParentPixels | B::ParentDefined => (self.header.parent.as_mut(), "parent"),
        };
        let plane = plane.ok_or_else(|| {
            invalid(format!(
                "a LoadLevel piece is for the {what} plane, which the header does not have"
            ))
        })?;
        let size = plane.width as usize * plane.height as usize;
        let (buf, name) = match buffer {
            B::SamplePixels | B::ParentPixels => (&mut plane.pixels, "pixels"),
            _ => (&mut plane.defined, "defined-mask"),
        };
        if buf.len() + piece.data.len() > size {
            return Err(invalid(format!(
                "LoadLevel sends more than the {size} bytes of the {what} plane's {name}"
            )));
        }
        if buf.is_empty() {
            buf.reserve_exact(size);
        }
        buf.extend_from_slice(&piece.data);
        Ok(())
    }

    /// The whole level, validated as one `LoadLevel` request.
    pub fn finish(self) -> Result<LevelLoad, Status> {
        LevelLoad::try_from(self.header)
    }
}

/// Pruning figures of one search as they travel in a `SearchResult`.
pub fn prune_to_proto(p: &PruneStats) -> pb::PruneCounts {
    pb::PruneCounts {
        pairs: p.pairs,
        pruned: p.pruned,
        chunks: p.chunks,
        chunks_full: p.chunks_full,
    }
}

/// The pruning figures of a `SearchResult` (zero when it carries none). They
/// only feed the run report, so they are taken as sent.
pub fn prune_from_proto(r: &pb::SearchResult) -> PruneStats {
    r.prune
        .as_ref()
        .map_or(PruneStats::default(), |p| PruneStats {
            pairs: p.pairs,
            pruned: p.pruned,
            chunks: p.chunks,
            chunks_full: p.chunks_full,
        })
}

/// The bounds of queries `qs` of a batch as the two `SearchBatch` fields
/// (index, distance); both empty when none of them has a bound.
pub fn bounds_to_proto(batch: &QueryBatch, qs: std::ops::Range<usize>) -> (Vec<u64>, Vec<u64>) {
    let b = &batch.bounds()[qs];
    if b.iter().all(Hit::is_none) {
        return (Vec::new(), Vec::new());
    }
    (
        b.iter().map(|h| h.index).collect(),
        b.iter().map(|h| h.dist).collect(),
    )
}

/// The per-query bounds of a `SearchBatch` ([`Hit::NONE`] each when it has
/// none), checked: both fields empty or both `count` long.
pub fn bounds_from_proto(b: &pb::SearchBatch) -> Result<Vec<Hit>, Status> {
    let count = b.count as usize;
    match (b.bound_index.len(), b.bound_distance.len()) {
        (0, 0) => Ok(vec![Hit::NONE; count]),
        (i, d) if i == count && d == count => Ok(b
            .bound_index
            .iter()
            .zip(&b.bound_distance)
            .map(|(&index, &dist)| Hit { index, dist })
            .collect()),
        (i, d) => Err(invalid(format!(
            "bound_index has {i} and bound_distance {d} entries; send none or one per query ({count})"
        ))),
    }
}

impl From<&pb::Hit> for Hit {
    fn from(h: &pb::Hit) -> Self {
        Hit {
            index: h.index,
            dist: h.distance,
        }
    }
}

impl From<&Hit> for pb::Hit {
    fn from(h: &Hit) -> Self {
        pb::Hit {
            index: h.index,
            distance: h.dist,
        }
    }
}

/// The best-1 hits of a result to a batch of `count` queries, checked for shape
/// (a worker with an empty range answers [`Hit::NONE`], which the merge ignores).
pub fn best_hits(result: &pb::SearchResult, count: usize) -> anyhow::Result<Vec<Hit>> {
    if result.per_query != 1 || result.hits.len() != count {
        bail!(
            "malformed best-1 answer: {} hits with per_query {} for {count} queries",
            result.hits.len(),
            result.per_query
        );
    }
    Ok(result.hits.iter().map(Hit::from).collect())
}

/// The top-k lists of a result to a batch of `count` queries, checked for shape.
pub fn topk_hits(result: &pb::SearchResult, count: usize) -> anyhow::Result<Vec<Vec<Hit>>> {
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
        .map(|c| c.iter().map(Hit::from).collect())
        .collect())
}

/// The line a worker prints on stdout once its listener is bound:
/// `listening on ADDR`. A parent that started it with port 0 reads the real
/// port from it with [`parse_listening_line`].
pub fn listening_line(addr: SocketAddr) -> String {
    format!("listening on {addr}")
}

/// Reads the address from a worker's `listening on ADDR` stdout line.
pub fn parse_listening_line(line: &str) -> Option<SocketAddr> {
    line.trim().strip_prefix("listening on ")?.parse().ok()
}

/// How often the carrier of a linked batch (the worker's stream, the master's
/// part task) passes on the distances lowered since its last look.
pub const LINK_INTERVAL: std::time::Duration = std::time::Duration::from_millis(1);

/// The lowered distances of an `update` or `interim` message (query within a
/// batch of `count`, distance), checked: the two lists equally long, every
/// query inside the batch.
pub fn lowered_from_proto(
    queries: &[u32],
    distances: &[u64],
    count: usize,
) -> Result<Vec<(usize, u64)>, String> {
    if queries.len() != distances.len() {
        return Err(format!(
            "lower_query has {} and lower_distance {} entries; send one distance per query",
            queries.len(),
            distances.len()
        ));
    }
    queries
        .iter()
        .zip(distances)
        .map(|(&q, &d)| {
            let q = q as usize;
            if q < count {
                Ok((q, d))
            } else {
                Err(format!(
                    "lower_query {q} is outside the batch of {count} queries"
                ))
            }
        })
        .collect()
}

/// `changes` (query, distance) as the two lists of an `update` or `interim`
/// message.
pub fn lowered_to_proto(changes: &[(u32, u64)]) -> (Vec<u32>, Vec<u64>) {
    changes.iter().copied().unzip()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: u32, h: u32, px: usize, def: usize) -> pb::Plane {
        pb::Plane {
            width: w,
            height: h,
            pixels: vec![0; px],
            defined: vec![1; def],
        }
    }

    #[test]
    fn planes_are_checked() {
        assert!(plane_from_proto(plane(4, 3, 12, 0), "s").is_ok());
        assert!(plane_from_proto(plane(4, 3, 12, 12), "s").is_ok());
        for bad in [
            plane(0, 3, 0, 0),
            plane(4, 3, 11, 0),
            plane(4, 3, 12, 5),
            plane(u32::MAX, u32::MAX, 0, 0),
        ] {
            let e = plane_from_proto(bad, "sample").unwrap_err();
            assert_eq!(e.code(), tonic::Code::InvalidArgument);
            assert!(e.message().starts_with("sample plane"), "{}", e.message());
        }
    }

    #[test]
    fn planes_round_trip() {
        let pixels: Vec<u8> = (0..12).collect();
        let defined = vec![1, 1, 0, 1, 1, 1, 1, 1, 1, 1, 1, 1];
        for mask in [None, Some(&defined[..])] {
            let p = Plane {
                width: 4,
                height: 3,
                pixels: &pixels,
                defined: mask,
            };
            let back = OwnedPlane::try_from(pb::Plane::from(&p)).unwrap();
            assert_eq!(back.view().pixels, p.pixels);
            assert_eq!(back.view().defined, p.defined);
        }
        let all = vec![1u8; 12];
        let p = Plane {
            width: 4,
            height: 3,
            pixels: &pixels,
            defined: Some(&all),
        };
        assert_eq!(
            OwnedPlane::try_from(pb::Plane::from(&p)).unwrap().defined,
            None
        );
    }

    #[test]
    fn job_ids_are_checked() {
        assert!(check_job_id("job-1").is_ok());
        assert!(check_job_id("").is_err());
        assert!(check_job_id(&"x".repeat(129)).is_err());
        assert!(check_job_id("a\nb").is_err());
    }

    #[test]
    fn geometry_is_checked_and_round_trips() {
        let g = |n, m, hi, lo, metric| pb::Geometry {
            neighbourhood: n,
            parent_window: m,
            weight_hi: hi,
            weight_lo: lo,
            metric,
        };
        let (geo, params) = geometry_from_proto(Some(&g(5, 3, 1, 2, 1))).unwrap();
        assert_eq!(geometry_to_proto(&geo, &params), g(5, 3, 1, 2, 1));
        assert!(geometry_from_proto(None).is_err());
        assert!(geometry_from_proto(Some(&g(4, 3, 1, 1, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 2, 1, 1, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 3, 0, 0, 0))).is_err());
        assert!(geometry_from_proto(Some(&g(5, 3, 1, 1, 7))).is_err());
    }

    #[test]
    fn load_level_requests_are_checked_and_round_trip() {
        let px: Vec<u8> = (0..64).collect();
        let pp: Vec<u8> = (0..16).collect();
        let sample = Sample {
            fine: Plane::new(8, 8, &px, None).unwrap(),
            parent: Some(Plane::new(4, 4, &pp, None).unwrap()),
        };
        let g = Geometry::new(3, 3).unwrap();
        let r = load_level_request("job", 2, &g, &Params::default(), &sample);
        let l = LevelLoad::try_from(r.clone()).unwrap();
        assert_eq!((l.job_id.as_str(), l.level, l.geometry), ("job", 2, g));
        assert_eq!(l.plane_bytes(), 64 + 16);
        // x, y in 1..=6 (3×3 window) with x/2, y/2 in 1..=2 (3×3 parent window).
        assert_eq!(l.locate().unwrap().total(), 4 * 4);
        let mut bad = r.clone();
        bad.parent = None;
        let e = LevelLoad::try_from(bad).unwrap_err();
        assert!(e.message().contains("no parent plane"), "{}", e.message());
        let mut bad = r.clone();
        bad.job_id.clear();
        assert_eq!(
            LevelLoad::try_from(bad).unwrap_err().code(),
            tonic::Code::InvalidArgument
        );
        let mut bad = r;
        bad.sample = None;
        let e = LevelLoad::try_from(bad).unwrap_err();
        assert_eq!(e.message(), "the sample plane is missing");
    }

    #[test]
    fn listening_line_round_trips() {
        let a: SocketAddr = "127.0.0.1:40123".parse().unwrap();
        assert_eq!(parse_listening_line(&listening_line(a)), Some(a));
        assert_eq!(
            parse_listening_line("listening on [::1]:7\n"),
            "[::1]:7".parse().ok()
        );
        assert_eq!(parse_listening_line("hello"), None);
    }

    #[test]
    fn result_shapes_are_checked() {
        let r = pb::SearchResult {
            batch_id: 0,
            hits: vec![
                pb::Hit {
                    index: 1,
                    distance: 2
                };
                4
            ],
            per_query: 2,
            seconds: 0.0,
            prune: None,
            ..Default::default()
        };
        assert_eq!(topk_hits(&r, 2).unwrap().len(), 2);
        assert!(topk_hits(&r, 3).is_err());
        assert!(best_hits(&r, 4).is_err());
    }
}
