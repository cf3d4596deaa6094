//! The analysis of an exemplar done once (Lefebvre and Hoppe precompute it;
//! Manke–Wünsche §3 take it as given): the k-coherence candidate sets of
//! every level, kept in a directory so that a second synthesis, morph or
//! solid from the same exemplars skips their search.
//!
//! A file is named by the SHA-256 of everything the sets depend on: the
//! level's appearance vectors (which hold the exemplar, the blur and the
//! appearance space of the whole exemplar set), its size, the spacing, k and
//! [`FORMAT`]. A hit is therefore the bytes the search would give; a file
//! that does not read back whole and in range is searched again and
//! rewritten, never used. Files are written atomically, so runs side by side
//! may share a directory.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};

use super::candidates::{Candidates, SetsOf, EXACT_PIXELS, MAX_K, SEARCH_DIMS};
use crate::imaging;

/// Version of the file layout and of the search that fills it: a change to
/// either must bump it, so old files are not read as new (2: large levels
/// gridded at least at their near-duplicate radius).
const FORMAT: u32 = 2;
/// First bytes of a file.
const MAGIC: &[u8; 8] = b"TXSYNKC\0";
/// Header: magic, format, key, then k, stride, width, height.
const HEADER: usize = 8 + 4 + 32 + 4 * 4;
/// Largest file read back (a 4096² level at k = 16).
const MAX_BYTES: u64 = HEADER as u64 + 4096 * 4096 * MAX_K as u64 * 8;

/// A directory of candidate sets (`--candidate-cache`).
#[derive(Clone, Debug)]
pub struct CandidateCache {
    dir: PathBuf,
}

/// The key of `of`'s file: SHA-256 of every input of the search, in a fixed
/// little-endian layout.
fn key_of(of: &SetsOf<'_>) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(MAGIC);
    for v in [
        FORMAT as u64,
        of.size.0 as u64,
        of.size.1 as u64,
        of.dims as u64,
        of.spacing.stride as u64,
        u64::from(of.spacing.radius),
        of.k as u64,
        SEARCH_DIMS as u64,
        EXACT_PIXELS as u64,
    ] {
        h.update(v.to_le_bytes());
    }
    for a in of.appearance {
        h.update(a.to_le_bytes());
    }
    h.finalize().into()
}

impl CandidateCache {
    /// The cache in `dir`, created if missing.
    pub fn open(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| {
            format!(
                "--candidate-cache {}: cannot create the directory; give a writable one",
                dir.display()
            )
        })?;
        anyhow::ensure!(
            dir.is_dir(),
            "--candidate-cache {} is not a directory; give a directory",
            dir.display()
        );
        Ok(Self {
            dir: dir.to_path_buf(),
        })
    }

    fn path(&self, key: &[u8; 32]) -> PathBuf {
        let hex: String = key.iter().map(|b| format!("{b:02x}")).collect();
        self.dir.join(format!("{hex}.kcs"))
    }

    /// The sets of `of` from the cache, or from `search` (then stored). The
    /// second value is true on a hit.
    pub fn get_or_search(
        &self,
        of: &SetsOf<'_>,
        search: impl FnOnce() -> Result<Candidates>,
    ) -> Result<(Candidates, bool)> {
        let key = key_of(of);
        let path = self.path(&key);
        if path.exists() {
            match read(&path, &key, of) {
                Ok(c) => return Ok((c, true)),
                Err(e) => tracing::warn!(
                    file = %path.display(),
                    "candidate cache file unusable ({e:#}); searching the sets again"
                ),
            }
        }
        let c = search()?;
        imaging::save_bytes(&path, &encode(&key, &c)).with_context(|| {
            format!(
                "--candidate-cache {}: cannot store the candidate sets",
                self.dir.display()
            )
        })?;
        Ok((c, false))
    }
}

/// The file of `c` under `key`.
fn encode(key: &[u8; 32], c: &Candidates) -> Vec<u8> {
    let (w, h) = c.size();
    let table = c.entries();
    let mut out = Vec::with_capacity(HEADER + table.len() * 8);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&FORMAT.to_le_bytes());
    out.extend_from_slice(key);
    for v in [c.k(), c.stride(), w, h] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    for p in table {
        out.extend_from_slice(&p[0].to_le_bytes());
        out.extend_from_slice(&p[1].to_le_bytes());
    }
    out
}

/// Reads and checks the file of `key`: its header must name `key` and `of`'s
/// size and k, its length fit, and every entry lie inside the level.
fn read(path: &Path, key: &[u8; 32], of: &SetsOf<'_>) -> Result<Candidates> {
    let bytes = imaging::read_regular(path, MAX_BYTES, "candidate cache file")?;
    decode(&bytes, key, of)
}

fn decode(bytes: &[u8], key: &[u8; 32], of: &SetsOf<'_>) -> Result<Candidates> {
    anyhow::ensure!(bytes.len() >= HEADER, "shorter than its header");
    anyhow::ensure!(&bytes[..8] == MAGIC, "not a candidate cache file");
    let word = |at: usize| word_at(bytes, at);
    anyhow::ensure!(word(8) == FORMAT, "format {}, not {FORMAT}", word(8));
    anyhow::ensure!(&bytes[12..44] == key, "written for other inputs");
    let [k, stride, w, h] = [44, 48, 52, 56].map(|at| word(at) as usize);
    anyhow::ensure!(
        k == of.k && (w, h) == of.size && stride >= 1,
        "holds k = {k} at {w}×{h}, stride {stride}"
    );
    let n = w * h * k;
    anyhow::ensure!(
        bytes.len() == HEADER + n * 8,
        "{} bytes where {} were written",
        bytes.len(),
        HEADER + n * 8
    );
    let table: Vec<[u32; 2]> = bytes[HEADER..]
        .chunks_exact(8)
        .map(|c| [word_at(c, 0), word_at(c, 4)])
        .collect();
    anyhow::ensure!(
        table
            .iter()
            .all(|p| (p[0] as usize) < w && (p[1] as usize) < h),
        "an entry lies outside the {w}×{h} level"
    );
    Ok(Candidates::from_parts(k, stride, (w, h), table))
}

fn word_at(c: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(c[at..at + 4].try_into().expect("4 bytes"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parallel::candidates::Spacing;

    fn sets(appearance: &[f32]) -> SetsOf<'_> {
        SetsOf {
            appearance,
            size: (4, 2),
            dims: 1,
            spacing: Spacing {
                stride: 1,
                radius: 2,
            },
            k: 2,
        }
    }

    fn candidates() -> Candidates {
        let table = (0..16u32).map(|i| [i % 4, (i / 4) % 2]).collect();
        Candidates::from_parts(2, 1, (4, 2), table)
    }

    #[test]
    fn a_stored_set_reads_back_and_a_miss_searches_once() {
        let dir = tempfile::tempdir().unwrap();
        let cache = CandidateCache::open(&dir.path().join("kc")).unwrap();
        let a = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        let (first, hit) = cache.get_or_search(&sets(&a), || Ok(candidates())).unwrap();
        assert!(!hit);
        let (second, hit) = cache
            .get_or_search(&sets(&a), || panic!("a hit must not search"))
            .unwrap();
        assert!(hit);
        assert_eq!(second.entries(), first.entries());
        assert_eq!((second.k(), second.stride()), (2, 1));
        // Other appearance, other key: searched.
        let b = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.5];
        let (_, hit) = cache.get_or_search(&sets(&b), || Ok(candidates())).unwrap();
        assert!(!hit);
    }

    #[test]
    fn a_damaged_file_is_searched_again_and_rewritten() {
        let dir = tempfile::tempdir().unwrap();
        let cache = CandidateCache::open(dir.path()).unwrap();
        let a = [0.5f32; 8];
        let of = sets(&a);
        cache.get_or_search(&of, || Ok(candidates())).unwrap();
        let path = cache.path(&key_of(&of));
        let good = std::fs::read(&path).unwrap();
        let damages: Vec<Vec<u8>> = vec![
            good[..good.len() - 1].to_vec(),
            {
                let mut b = good.clone();
                b[HEADER] = 9; // x = 9 on a 4-wide level
                b
            },
            {
                let mut b = good.clone();
                b[20] ^= 1; // the key
                b
            },
            b"not a cache".to_vec(),
        ];
        for bad in damages {
            std::fs::write(&path, &bad).unwrap();
            let mut searched = false;
            let (c, hit) = cache
                .get_or_search(&of, || {
                    searched = true;
                    Ok(candidates())
                })
                .unwrap();
            assert!(searched && !hit);
            assert_eq!(c.entries(), candidates().entries());
            assert_eq!(std::fs::read(&path).unwrap(), good, "rewritten whole");
        }
    }

    #[test]
    fn a_file_in_place_of_the_directory_is_refused_by_flag_name() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f");
        std::fs::write(&file, b"x").unwrap();
        let e = CandidateCache::open(&file).unwrap_err();
        assert!(format!("{e:#}").contains("--candidate-cache"), "{e:#}");
    }
}
