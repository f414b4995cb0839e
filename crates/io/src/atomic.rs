//! Outputs that appear whole or not at all.
//!
//! Every file kfuse writes goes first to a hidden temporary name in the same directory and is
//! renamed into place when complete (a rename within one directory is atomic on POSIX), so a
//! crash, a full disk or a bad input never leaves a truncated file behind. Multi-file outputs
//! use [`StagedDir`]: all files are written into a hidden sibling directory and moved into the
//! destination only by [`StagedDir::commit`]; dropping it uncommitted deletes everything.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use geometry::GeometryError;

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> GeometryError + '_ {
    move |source| GeometryError::Io { path: path.to_path_buf(), source }
}

/// The hidden temporary sibling of `path` used while it is being written.
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// Writes `path` atomically: `write` fills a temporary file which is synced and renamed to
/// `path` only if `write` succeeds. On error the temporary file is removed.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), GeometryError>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let tmp = temporary_name(path);
    let result = (|| {
        let file = fs::File::create(&tmp)?;
        let mut buffered = std::io::BufWriter::new(file);
        write(&mut buffered)?;
        let file = buffered.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(io_err(path))
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// A directory of outputs that becomes visible only when complete.
///
/// Files are created under [`StagedDir::path`] (a hidden sibling of the destination);
/// [`StagedDir::commit`] moves each of them into the destination (created if needed,
/// existing files of the same name replaced). Dropped without commit, the staging directory
/// and everything in it is deleted.
#[derive(Debug)]
pub struct StagedDir {
    staging: PathBuf,
    destination: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Starts staging outputs for `destination`.
    pub fn new(destination: &Path) -> Result<Self, GeometryError> {
        let parent = match destination.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).map_err(io_err(&parent))?;
        let name = destination
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
        }
        fs::create_dir_all(&staging).map_err(io_err(&staging))?;
        Ok(Self { staging, destination: destination.to_path_buf(), committed: false })
    }

    /// Where to write the files now.
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// A path inside the staging directory.
    pub fn join(&self, name: impl AsRef<Path>) -> PathBuf {
        self.staging.join(name)
    }

    /// The final directory.
    pub fn destination(&self) -> &Path {
        &self.destination
    }

    /// Moves every staged entry into the destination and removes the staging directory.
    pub fn commit(mut self) -> Result<PathBuf, GeometryError> {
        fs::create_dir_all(&self.destination).map_err(io_err(&self.destination))?;
        let entries = fs::read_dir(&self.staging).map_err(io_err(&self.staging))?;
        for entry in entries {
            let entry = entry.map_err(io_err(&self.staging))?;
            let target = self.destination.join(entry.file_name());
            if target.is_dir() {
                fs::remove_dir_all(&target).map_err(io_err(&target))?;
            }
            fs::rename(entry.path(), &target).map_err(io_err(&target))?;
        }
        fs::remove_dir(&self.staging).map_err(io_err(&self.staging))?;
        self.committed = true;
        Ok(self.destination.clone())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kfuse-atomic-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn failed_write_leaves_nothing_and_keeps_the_old_file() {
        let dir = scratch("fail");
        let path = dir.join("out.bin");
        write_bytes_atomic(&path, b"old").unwrap();
        let err = write_atomic(&path, |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("disk full"))
        });
        assert!(err.is_err());
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1, "temporary file left behind");
    }

    #[test]
    fn staged_dir_appears_only_on_commit() {
        let dir = scratch("staged");
        let dest = dir.join("results");
        {
            let staged = StagedDir::new(&dest).unwrap();
            fs::write(staged.join("a.txt"), "a").unwrap();
            // dropped without commit
        }
        assert!(!dest.exists());
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 0, "staging directory left behind");
        let staged = StagedDir::new(&dest).unwrap();
        fs::write(staged.join("a.txt"), "a").unwrap();
        staged.commit().unwrap();
        assert_eq!(fs::read_to_string(dest.join("a.txt")).unwrap(), "a");
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1);
    }
}
