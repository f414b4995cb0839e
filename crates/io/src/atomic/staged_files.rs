//! Several single files that appear together or not at all.

use super::*;

/// Single files (e.g. `rig.json` and an OpenCV YAML beside it) that appear together or not at
/// all: [`StagedFiles::add`] writes each to its hidden temporary sibling, [`StagedFiles::commit`]
/// renames them all into place; dropped without commit, the temporaries are deleted.
#[derive(Debug, Default)]
pub struct StagedFiles {
    files: Vec<(PathBuf, PathBuf)>,
    committed: bool,
}

impl StagedFiles {
    /// No files yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Writes `bytes` for `path` (to its temporary sibling; `path` itself is untouched). The
    /// temporaries of killed runs for the same name are removed first. As [`write_atomic`], a
    /// symbolic link is written through and anything but a regular file is refused.
    pub fn add(&mut self, path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
        let path = &writable_target(path)?;
        let tmp = temporary_name(path);
        if let (Some(dir), Some(name)) = (tmp.parent(), path.file_name()) {
            let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
            let prefix = format!(".{}.partial-", name.to_string_lossy());
            remove_stale_files(dir, &prefix);
        }
        let result = (|| {
            let mut file = track_created(&tmp, || fs::File::create(&tmp))?;
            file.write_all(bytes)?;
            file.sync_all()
        })();
        // Recorded before the result is checked, so a half-written temporary is removed too.
        self.files.push((tmp, path.to_path_buf()));
        result.map_err(io_err(path))
    }

    /// Renames every file into place.
    pub fn commit(mut self) -> Result<(), GeometryError> {
        let _publishing = lock(&PUBLISHING);
        for (tmp, path) in &self.files {
            fs::rename(tmp, path).map_err(io_err(path))?;
        }
        self.committed = true;
        Ok(())
    }
}

impl Drop for StagedFiles {
    fn drop(&mut self) {
        for (tmp, _) in &self.files {
            if !self.committed {
                let _ = fs::remove_file(tmp);
            }
            untrack(tmp);
        }
    }
}
