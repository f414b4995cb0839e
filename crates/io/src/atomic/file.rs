//! Single files written whole: a hidden temporary sibling renamed into place.

use super::*;

/// The hidden temporary sibling of `path` used while it is being written.
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}.partial-{}", std::process::id()))
}

/// The file that writing `path` replaces: `path` itself (missing or a regular file), or the
/// regular file that a symbolic link at `path` points to (written through, the link stays).
/// Refused with one line naming the path: a folder, a device, a pipe or a socket there (an
/// atomic write renames a new file over the path, which would replace `/dev/null` or a FIFO
/// with a plain file), or a link to nothing.
pub fn writable_target(path: &Path) -> Result<PathBuf, GeometryError> {
    let refuse = |message: &str| GeometryError::Format {
        path: path.to_path_buf(),
        message: message.to_string(),
    };
    let not_a_file = "exists and is not a regular file (a folder, device, pipe or socket); kfuse writes its outputs to files: give a file name such as out.json";
    match fs::symlink_metadata(path) {
        Err(_) => Ok(path.to_path_buf()),
        Ok(m) if m.is_file() => Ok(path.to_path_buf()),
        Ok(m) if m.file_type().is_symlink() => match fs::canonicalize(path) {
            Ok(target) if target.is_file() => Ok(target),
            Ok(_) => Err(refuse(&format!("is a link to something that {not_a_file}"))),
            Err(_) => Err(refuse(
                "is a symbolic link to a missing file; remove the link or give another file name",
            )),
        },
        Ok(_) => Err(refuse(not_a_file)),
    }
}

/// Writes `path` atomically: `write` fills a temporary file which is synced and renamed to
/// `path` only if `write` succeeds. On error the temporary file is removed. A symbolic link
/// at `path` is written through; anything but a regular file there is refused
/// ([`writable_target`]).
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), GeometryError>
where
    F: FnOnce(&mut dyn Write) -> std::io::Result<()>,
{
    let path = &writable_target(path)?;
    remove_stale_temporaries(path);
    let tmp = temporary_name(path);
    let result = (|| {
        let file = track_created(&tmp, || fs::File::create(&tmp))?;
        let mut buffered = std::io::BufWriter::new(file);
        write(&mut buffered)?;
        let file = buffered.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    untrack(&tmp);
    result.map_err(io_err(path))
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// Removes the temporary files of `path` ([`temporary_name`]) that killed kfuse runs left
/// (`kill -9`, power loss: `.rig.json.partial-4242`), so that the folder holds no hidden
/// leftovers once `path` is written again. Files of a running process and files named
/// otherwise are left alone. Skipped inside a staging folder, which this process created empty
/// (a sequence writes thousands of files there: one folder listing each would cost seconds).
fn remove_stale_temporaries(path: &Path) {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else { return };
    let dir = if dir.as_os_str().is_empty() { Path::new(".") } else { dir };
    let in_staging = dir.file_name().is_some_and(|d| d.to_string_lossy().contains(STAGING_PREFIX));
    if in_staging {
        return;
    }
    remove_stale_files(dir, &format!(".{}.partial-", name.to_string_lossy()));
}

/// Removes `{prefix}{pid}` files of processes that are gone.
pub(super) fn remove_stale_files(dir: &Path, prefix: &str) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = name.strip_prefix(prefix).and_then(|r| r.parse::<u32>().ok()) else {
            continue;
        };
        let is_file = entry.file_type().map(|t| t.is_file()).unwrap_or(false);
        if is_file && pid != std::process::id() && !process_alive(pid) {
            let _ = fs::remove_file(entry.path());
        }
    }
}
