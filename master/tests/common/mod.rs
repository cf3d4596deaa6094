//! Fixtures shared by the master's integration tests: the bundled textures,
//! the `texsyn` binary, a library run and the seam statistic of tiling tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use texsyn::block::Silent;
use texsyn::imaging::{self, ColorImage};
use texsyn::search::{LocalSearch, Plan, PlannedSearch};
use texsyn::{synthesize, Config, Mode};
use texsyn_engine::Engine;

/// The bundled textures (`assets/textures`).
pub fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/textures")
}

/// Runs the `texsyn` binary built for these tests.
pub fn texsyn(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_texsyn"))
        .args(args)
        .output()
        .expect("run texsyn")
}

/// Runs texsyn and asserts it succeeded; its output.
pub fn ok(args: &[&str]) -> Output {
    let r = texsyn(args);
    assert!(
        r.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&r.stderr)
    );
    r
}

/// Runs texsyn and asserts it failed; its stderr.
pub fn refused(args: &[&str]) -> String {
    let r = texsyn(args);
    assert!(!r.status.success(), "{args:?} succeeded");
    String::from_utf8_lossy(&r.stderr).into_owned()
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A bundled texture as the search sees it (8-bit RGB).
pub fn texture(name: &str) -> ColorImage {
    imaging::load_color(&assets().join(name)).unwrap()
}

/// A local exact synthesis on `threads` threads.
pub fn run(sample: &ColorImage, mode: &Mode, cfg: &Config, threads: usize) -> texsyn::Output {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut backend = PlannedSearch::new(
        Plan::Exact,
        LocalSearch::new(Engine::default().with_min_chunk(256)),
    );
    pool.install(|| synthesize(sample, mode, cfg, &mut backend, &Silent))
        .unwrap()
}

/// Mean absolute luminance step across each vertical pixel boundary: element x
/// is the step between columns x and x+1, the last one is the wrap-around edge
/// (column w-1 to column 0). `transpose` does the same for rows.
pub fn column_steps(img: &ColorImage, transpose: bool) -> Vec<f64> {
    let g = texsyn::imaging::colour::luminance(img);
    let (w, h) = if transpose {
        (g.height, g.width)
    } else {
        (g.width, g.height)
    };
    let at = |x: usize, y: usize| f64::from(if transpose { g.get(y, x) } else { g.get(x, y) });
    (0..w)
        .map(|x| {
            (0..h)
                .map(|y| (at(x, y) - at((x + 1) % w, y)).abs())
                .sum::<f64>()
                / h as f64
        })
        .collect()
}

/// (wrap-around step, largest interior step, mean interior step).
pub fn seam(img: &ColorImage, transpose: bool) -> (f64, f64, f64) {
    let s = column_steps(img, transpose);
    let (inner, wrap) = s.split_at(s.len() - 1);
    let max = inner.iter().cloned().fold(0.0, f64::max);
    (wrap[0], max, inner.iter().sum::<f64>() / inner.len() as f64)
}
