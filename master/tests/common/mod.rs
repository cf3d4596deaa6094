//! Fixtures shared by the master's integration tests: the bundled textures
//! and the `texsyn` binary.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

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

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
