//! Output paths checked before any work: every output is a different file,
//! none is an input, and no output lands on a `--levels-dir` level file.
//! Shared by every command.
//!
//! Files need not exist yet, so a path is compared as the canonical form of
//! its longest existing ancestor plus the rest ([`place`]); an input is also
//! compared by its fully resolved path.

use std::ffi::OsStr;
use std::path::{Component, Path, PathBuf};

use anyhow::{bail, Result};

/// `p` with its longest existing ancestor canonicalised and the rest kept.
pub fn resolve(p: &Path) -> PathBuf {
    let mut rest = Vec::new();
    let mut cur = p;
    loop {
        let probe = if cur.as_os_str().is_empty() {
            Path::new(".")
        } else {
            cur
        };
        if let Ok(mut c) = probe.canonicalize() {
            for r in rest.iter().rev() {
                match r {
                    Component::ParentDir => {
                        c.pop();
                    }
                    Component::CurDir => {}
                    other => c.push(other),
                }
            }
            return c;
        }
        match (cur.components().next_back(), cur.parent()) {
            (Some(last), Some(parent)) => {
                rest.push(last);
                cur = parent;
            }
            _ => return p.to_path_buf(),
        }
    }
}

/// Where a file named by `p` goes: its resolved directory plus its name (the
/// directory entry itself, not what a symlink there points to).
pub fn place(p: &Path) -> PathBuf {
    match (p.parent(), p.file_name()) {
        (Some(dir), Some(name)) => resolve(dir).join(name),
        _ => resolve(p),
    }
}

/// True for the names `--levels-dir` writes (`level<N>.png`).
fn is_level_file(name: &OsStr) -> bool {
    name.to_str()
        .and_then(|n| n.strip_prefix("level"))
        .and_then(|n| n.strip_suffix(".png"))
        .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
}

/// Rejects `outputs` (flag, path) that name the same file or an input of
/// `inputs`, or a level file of `levels_dir`.
pub fn check_files(
    outputs: &[(&str, &Path)],
    inputs: &[(&str, &Path)],
    levels_dir: Option<&Path>,
) -> Result<()> {
    let placed: Vec<(&str, &Path, PathBuf)> =
        outputs.iter().map(|&(f, p)| (f, p, place(p))).collect();
    for (i, (fa, pa, a)) in placed.iter().enumerate() {
        for (fb, _, b) in &placed[i + 1..] {
            if a == b {
                bail!(
                    "{fa} and {fb} both name {}; give each output its own file",
                    pa.display()
                );
            }
        }
        for &(fi, input) in inputs {
            let real = input.canonicalize().ok();
            if *a == place(input) || real.as_ref() == Some(a) {
                bail!(
                    "{fa} {} is the {fi} {}; write the result to another file so the input is kept",
                    pa.display(),
                    input.display()
                );
            }
        }
    }
    if let Some(dir) = levels_dir {
        let levels = resolve(dir);
        let clash = |p: &Path| {
            p == levels
                || (p.parent() == Some(levels.as_path())
                    && p.file_name().is_some_and(is_level_file))
        };
        for (f, p, a) in &placed {
            if clash(a) {
                bail!(
                    "{f} {} would be overwritten by the level images of --levels-dir {}; give another file name or directory",
                    p.display(),
                    dir.display()
                );
            }
        }
        for &(f, p) in inputs {
            if clash(&place(p)) || p.canonicalize().is_ok_and(|real| clash(&real)) {
                bail!(
                    "the {f} {} would be overwritten by the level images of --levels-dir {}; choose another --levels-dir",
                    p.display(),
                    dir.display()
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_file_names() {
        assert!(is_level_file(OsStr::new("level0.png")));
        assert!(is_level_file(OsStr::new("level12.png")));
        assert!(!is_level_file(OsStr::new("level.png")));
        assert!(!is_level_file(OsStr::new("levelx.png")));
        assert!(!is_level_file(OsStr::new("out.png")));
    }

    #[test]
    fn missing_files_resolve_through_existing_ancestors() {
        let dir = tempfile::tempdir().unwrap();
        let real = dir.path().canonicalize().unwrap();
        assert_eq!(
            place(&dir.path().join("a/../b.png")),
            real.join("b.png"),
            "a missing directory and .. are resolved"
        );
        assert_eq!(place(&dir.path().join("new/x.png")), real.join("new/x.png"));
        assert_eq!(place(&dir.path().join("./y.png")), real.join("y.png"));
    }
}
