//! Lattice phase (ARCHITECTURE §3.14): samples laid on a regular grid
//! (tiles, mosaics, stack-bond brick) keep their grid in the output.
//!
//! The exact best match of a block inside a plain tile sees no joint, so it
//! may come from any place in any tile, and the grid slips there: tiles grow
//! to odd sizes and joints end mid-tile. With `--lattice W×H` the backend
//! answers each query's near-ties (the same lists on every thread and worker
//! count) and the master takes the one whose copy offset (canvas position
//! less sample position) lies nearest the lattice through the offset of the
//! pixels known before the search (in tenths of a pixel of the level), then
//! the nearer, then the lower index. A period need not be whole: on a photo's
//! 31.6-px grid a tolerance of a pixel let neighbouring blocks take offsets a
//! pixel apart, and the joints wobbled.

use texsyn_engine::Hit;

/// Near-ties asked per query under the lattice rule: a plain tile's best
/// matches are spread over every phase, so enough of them must be asked for
/// one in phase to be among them.
pub const CANDIDATES: usize = 32;
/// Near-tie slack under the lattice rule, in percent of the best distance.
pub const PERCENT: u32 = 300;

/// The lattice rule's pick among the near-ties `hits` (sorted by distance,
/// then index): the least phase error (`error`), then the nearer, then the
/// lower index.
pub(super) fn pick(hits: &[Hit], error: impl Fn(&Hit) -> u32) -> Option<Hit> {
    hits.iter()
        .map(|h| (error(h), h.dist, h.index))
        .min()
        .map(|(_, dist, index)| Hit { index, dist })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(index: u64, dist: u64) -> Hit {
        Hit { index, dist }
    }

    #[test]
    fn the_near_tie_in_phase_wins_then_the_nearer() {
        let hits = [hit(5, 100), hit(2, 110), hit(9, 130), hit(1, 130)];
        let err = |h: &Hit| match h.index {
            5 => 3,
            2 => 1,
            _ => 0,
        };
        assert_eq!(pick(&hits, err), Some(hit(1, 130)));
        assert_eq!(pick(&hits[..2], err), Some(hit(2, 110)));
        assert_eq!(pick(&[], err), None);
    }
}
