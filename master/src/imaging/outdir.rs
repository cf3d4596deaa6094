//! Directory outputs written atomically (tile sets, solids, replays, frames):
//! the files go into a hidden temporary directory beside the target, which is
//! renamed into place only when the whole set is written. A failed run leaves
//! the old set whole, and no stale file of an older set survives next to a
//! new one.
//!
//! A target that already exists is replaced only when it is empty or was
//! written this way (it holds the [`MARKER`] file), so a user's directory of
//! other files is never deleted; no input may lie inside the target.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{bail, Context, Result};

use crate::cleanup::{self, Registration, Temporary};

/// The file that marks a directory as a texsyn output set.
pub const MARKER: &str = ".texsyn-output";

/// A directory output being written; [`OutputDir::commit`] puts it in place,
/// dropping it uncommitted removes what was written.
pub struct OutputDir {
    target: PathBuf,
    tmp: PathBuf,
    committed: bool,
    _registration: Registration,
}

/// Checks that `target` can take a directory output (a new path, an empty
/// directory or an earlier output set) and that none of `inputs`
/// (flag, path) lies inside it.
pub fn check_output_dir(target: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    target.file_name().with_context(|| {
        format!(
            "-o {} has no directory name; name the output directory",
            target.display()
        )
    })?;
    match fs::symlink_metadata(target) {
        Err(_) => {}
        Ok(m) if m.is_dir() => {
            let mut entries = fs::read_dir(target).with_context(|| {
                format!("cannot read the output directory {}", target.display())
            })?;
            let empty = entries.next().is_none();
            if !empty && !target.join(MARKER).is_file() {
                bail!(
                    "-o {} exists and holds files texsyn did not write; give a new or empty directory",
                    target.display()
                );
            }
        }
        Ok(_) => bail!(
            "-o {} exists and is not a directory; give a directory path",
            target.display()
        ),
    }
    let dir = super::paths::resolve(target);
    for &(flag, input) in inputs {
        let inside = |p: &Path| p.starts_with(&dir);
        if inside(&super::paths::place(input)) || input.canonicalize().is_ok_and(|r| inside(&r)) {
            bail!(
                "the {flag} {} lies inside the output directory {}, which is replaced as a whole; write the output elsewhere",
                input.display(),
                target.display()
            );
        }
    }
    Ok(())
}

impl OutputDir {
    /// Starts a directory output at `target` (checked with
    /// [`check_output_dir`]), creating its missing parents.
    pub fn create(target: &Path, inputs: &[(&str, &Path)]) -> Result<Self> {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        check_output_dir(target, inputs)?;
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).with_context(|| {
            format!(
                "cannot create the directory {} of -o {}",
                parent.display(),
                target.display()
            )
        })?;
        let name = target.file_name().unwrap_or_default().to_string_lossy();
        let tmp = parent.join(format!(
            ".{name}.tmp-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let (_, registration) = cleanup::register(
            || fs::create_dir(&tmp),
            |_| Temporary::Dir(tmp.clone()),
            || std::io::Error::other("interrupted: the process is ending"),
        )
        .with_context(|| format!("cannot create a directory in {}", parent.display()))?;
        fs::write(
            tmp.join(MARKER),
            b"written by texsyn; replaced as a whole by the next run\n",
        )
        .with_context(|| format!("cannot write in {}", tmp.display()))?;
        Ok(OutputDir {
            target: target.to_path_buf(),
            tmp,
            committed: false,
            _registration: registration,
        })
    }

    /// Where to write the files now.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Puts the written set in place of the target, replacing an older set.
    pub fn commit(mut self) -> Result<()> {
        let mut old = self.tmp.clone().into_os_string();
        old.push(".old");
        let old = PathBuf::from(old);
        let had_old = self.target.exists();
        if had_old {
            fs::rename(&self.target, &old)
                .with_context(|| format!("cannot move the old {} aside", self.target.display()))?;
        }
        if let Err(e) = fs::rename(&self.tmp, &self.target) {
            if had_old {
                let _ = fs::rename(&old, &self.target);
            }
            return Err(e)
                .with_context(|| format!("cannot put {} in place", self.target.display()));
        }
        self.committed = true;
        if had_old {
            fs::remove_dir_all(&old)
                .with_context(|| format!("cannot remove the old set {}", old.display()))?;
        }
        Ok(())
    }
}

impl Drop for OutputDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_set_replaces_the_old_one_whole_and_an_uncommitted_one_leaves_it() {
        let root = std::env::temp_dir().join(format!("texsyn-outdir-{}", std::process::id()));
        let _ = fs::remove_dir_all(&root);
        fs::create_dir_all(&root).unwrap();
        let target = root.join("set");
        let a = OutputDir::create(&target, &[]).unwrap();
        fs::write(a.path().join("one"), b"1").unwrap();
        fs::write(a.path().join("stale"), b"s").unwrap();
        a.commit().unwrap();
        assert!(target.join("stale").is_file());
        let b = OutputDir::create(&target, &[]).unwrap();
        fs::write(b.path().join("one"), b"2").unwrap();
        drop(b);
        assert_eq!(fs::read(target.join("one")).unwrap(), b"1");
        let c = OutputDir::create(&target, &[]).unwrap();
        fs::write(c.path().join("one"), b"3").unwrap();
        c.commit().unwrap();
        assert_eq!(fs::read(target.join("one")).unwrap(), b"3");
        assert!(!target.join("stale").exists());
        // A directory of other files is refused, and so is an input inside the target.
        let user = root.join("user");
        fs::create_dir_all(&user).unwrap();
        fs::write(user.join("notes.txt"), b"x").unwrap();
        assert!(OutputDir::create(&user, &[]).is_err());
        assert!(user.join("notes.txt").is_file());
        let input = target.join("one");
        let e = OutputDir::create(&target, &[("sample", &input)])
            .err()
            .unwrap();
        assert!(e.to_string().contains("inside the output directory"), "{e}");
        let leftovers: Vec<_> = fs::read_dir(&root)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(leftovers.len(), 2, "{leftovers:?}");
        fs::remove_dir_all(&root).unwrap();
    }
}
