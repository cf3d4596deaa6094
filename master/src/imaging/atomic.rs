//! Atomic file writes (ARCHITECTURE §3.10): write a hidden temporary file in
//! the target directory, sync it and rename it over the target, so a failed or
//! interrupted save never leaves a truncated file and keeps an existing one.
//! Each temp file is registered in [`crate::cleanup`] while it exists, so a
//! SIGINT or SIGTERM removes it too.

use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::{one_line, ImageIoError};
use crate::cleanup::{self, Registration, Temporary};

/// [`check_writable`] without the extension check, for non-image outputs.
pub fn check_writable_any(path: &Path) -> anyhow::Result<()> {
    let dir = target_dir(path)?;
    let tmp = temp_path(&dir, path)?;
    let (file, _registration) = create_temp(path, &dir, &tmp)?;
    drop(file);
    fs::remove_file(&tmp).map_err(|e| ImageIoError::Write {
        path: path.to_path_buf(),
        reason: format!(
            "cannot remove test file {}: {}",
            tmp.display(),
            one_line(&e)
        ),
    })?;
    Ok(())
}

/// The directory `path` goes into, checked to exist; also rejects a target
/// that is itself a directory.
fn target_dir(path: &Path) -> Result<PathBuf, ImageIoError> {
    let write = |reason: String| ImageIoError::Write {
        path: path.to_path_buf(),
        reason,
    };
    if path.file_name().is_none() {
        return Err(write("the path has no file name".into()));
    }
    if fs::metadata(path).is_ok_and(|m| m.is_dir()) {
        return Err(write("it is a directory".into()));
    }
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    match fs::metadata(&dir) {
        Ok(m) if m.is_dir() => Ok(dir),
        Ok(_) => Err(write(format!("{} is not a directory", dir.display()))),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Err(ImageIoError::NoDirectory {
            path: path.to_path_buf(),
            dir,
        }),
        Err(e) => Err(write(format!(
            "cannot access directory {}: {}",
            dir.display(),
            one_line(&e)
        ))),
    }
}

/// `.name.tmp-<pid>-<n>` next to the target; `n` keeps concurrent saves of
/// one process apart.
fn temp_path(dir: &Path, path: &Path) -> Result<PathBuf, ImageIoError> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| ImageIoError::Write {
        path: path.to_path_buf(),
        reason: "the path has no file name".into(),
    })?;
    let mut tmp = OsString::from(".");
    tmp.push(name);
    tmp.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    Ok(dir.join(tmp))
}

/// Creates the temp file `tmp`, registered for removal on a signal.
fn create_temp(path: &Path, dir: &Path, tmp: &Path) -> Result<(File, Registration), ImageIoError> {
    let interrupted = || ImageIoError::Write {
        path: path.to_path_buf(),
        reason: "interrupted: the process is ending".into(),
    };
    cleanup::register(
        || open_temp(path, dir, tmp),
        |_| Temporary::File(tmp.to_path_buf()),
        interrupted,
    )
}

fn open_temp(path: &Path, dir: &Path, tmp: &Path) -> Result<File, ImageIoError> {
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(tmp)
        .map_err(|e| ImageIoError::Write {
            path: path.to_path_buf(),
            reason: match e.kind() {
                io::ErrorKind::PermissionDenied => {
                    format!(
                        "directory {} is not writable (permission denied)",
                        dir.display()
                    )
                }
                _ => format!(
                    "cannot create a file in {}: {}",
                    dir.display(),
                    one_line(&e)
                ),
            },
        })
}

/// Removes the temporary file unless the save went through.
struct TempGuard<'a> {
    path: &'a Path,
    armed: bool,
}

impl Drop for TempGuard<'_> {
    fn drop(&mut self) {
        if self.armed {
            let _ = fs::remove_file(self.path);
        }
    }
}

/// Writes `path` atomically: `body` writes into a temp file in the same
/// directory, which is synced and renamed over `path`; on any error the temp
/// file is removed and an existing `path` stays untouched.
pub(super) fn write_atomic<F>(path: &Path, body: F) -> Result<(), ImageIoError>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<(), String>,
{
    let dir = target_dir(path)?;
    let tmp = temp_path(&dir, path)?;
    let (file, registration) = create_temp(path, &dir, &tmp)?;
    let mut guard = TempGuard {
        path: &tmp,
        armed: true,
    };
    let write = |reason: String| ImageIoError::Write {
        path: path.to_path_buf(),
        reason,
    };
    let mut w = BufWriter::new(file);
    body(&mut w).map_err(|r| write(format!("encoding failed: {r}")))?;
    let file = w.into_inner().map_err(|e| write(one_line(e.error())))?;
    file.sync_all().map_err(|e| write(one_line(&e)))?;
    drop(file);
    fs::rename(&tmp, path)
        .map_err(|e| write(format!("cannot replace the file: {}", one_line(&e))))?;
    guard.armed = false;
    drop(registration);
    // Persist the rename; best effort (not every platform can sync a directory).
    if let Ok(d) = File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}
