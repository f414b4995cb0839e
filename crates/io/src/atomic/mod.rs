//! Outputs that appear whole or not at all.
//!
//! Every file kfuse writes goes first to a hidden temporary name in the same directory and is
//! renamed into place when complete (a rename within one directory is atomic on POSIX), so a
//! crash, a full disk or a bad input never leaves a truncated file behind. Multi-file outputs
//! use [`StagedDir`]: all files are written into a hidden staging directory beside the
//! destination and published only by [`StagedDir::commit`] (one directory rename for a new
//! folder; an existing folder is replaced as a whole: old aside, new in, old removed, so a
//! killed run leaves the old folder or the new one, never a mixture; a folder that cannot be
//! replaced, `--out .` or a mount point, is published under a journal that the next run
//! finishes); dropping it uncommitted
//! deletes everything. A [`MANIFEST`] in each published folder lists what kfuse wrote, so
//! nothing of the user's is ever replaced.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use geometry::GeometryError;

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> GeometryError + '_ {
    move |source| GeometryError::Io { path: path.to_path_buf(), source }
}

/// A lock that a panicking holder did not spoil (the lists stay valid whatever panicked).
fn lock<T>(m: &'static Mutex<T>) -> MutexGuard<'static, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Whether process `pid` is still running (Linux: `/proc/PID` exists). Where `/proc` is not
/// available every process counts as running, so no staging folder is ever taken for stale.
fn process_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new(&format!("/proc/{pid}")).exists()
}

mod file;
mod in_place;
mod manifest;
mod staged_dir;
mod staged_files;
mod tracking;

use file::remove_stale_files;
pub use file::{temporary_name, writable_target, write_atomic, write_bytes_atomic};
pub use manifest::{MANIFEST, is_plain_name, written_by_kfuse};
use manifest::{STAGING_PREFIX, manifest_json, read_manifest};
pub use staged_dir::{KILL_AT_ENV, StagedDir};
pub use staged_files::StagedFiles;
use tracking::{PUBLISHING, track_created, untrack};
pub use tracking::{PublishingStopped, remove_unpublished};
#[cfg(test)]
mod tests;
