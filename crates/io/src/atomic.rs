//! Outputs that appear whole or not at all.
//!
//! Every file kfuse writes goes first to a hidden temporary name in the same directory and is
//! renamed into place when complete (a rename within one directory is atomic on POSIX), so a
//! crash, a full disk or a bad input never leaves a truncated file behind. Multi-file outputs
//! use [`StagedDir`]: all files are written into a hidden staging directory on the
//! destination's file system and published only by [`StagedDir::commit`] (one directory rename
//! for a new folder); dropping it uncommitted deletes everything. A [`MANIFEST`] in each
//! published folder lists what kfuse wrote, so nothing of the user's is ever replaced.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use geometry::GeometryError;

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> GeometryError + '_ {
    move |source| GeometryError::Io { path: path.to_path_buf(), source }
}

/// Temporary files and staging folders of this process that are neither published nor
/// removed yet: what [`remove_unpublished`] deletes when the process must stop at once.
static UNPUBLISHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Held while staged outputs are published, so that [`remove_unpublished`] never runs in the
/// middle of a publication of several files.
static PUBLISHING: Mutex<()> = Mutex::new(());

/// A lock that a panicking holder did not spoil (the lists stay valid whatever panicked).
fn lock<T>(m: &'static Mutex<T>) -> MutexGuard<'static, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Creates `path` with `create` and records it as unpublished, both under the lock that
/// [`remove_unpublished`] takes and keeps until the process exits: either the removal sees the
/// new path, or it ran first and this waits (until exit), so nothing is created behind its
/// back. (Recording first and creating after left a staging folder behind when the second
/// Ctrl-C came in between.)
fn track_created<T>(
    path: &Path,
    create: impl FnOnce() -> std::io::Result<T>,
) -> std::io::Result<T> {
    let mut unpublished = lock(&UNPUBLISHED);
    let created = create();
    if created.is_ok() {
        unpublished.push(path.to_path_buf());
    }
    created
}

/// Tries to remove an unpublished staging folder while this process's workers may still be
/// writing into it: renamed away first (a worker's later paths then lead nowhere), then
/// removed, again while a file created in the meantime makes the folder non-empty.
fn remove_staging(path: &Path) {
    // Still named `…{STAGING_PREFIX}{pid}`, so that a later run removes it if this one cannot.
    let doomed = path.with_file_name(format!(
        ".removing{}",
        path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    ));
    let target = if fs::rename(path, &doomed).is_ok() { doomed } else { path.to_path_buf() };
    for _ in 0..REMOVE_ATTEMPTS {
        if fs::remove_dir_all(&target).is_ok() || !target.exists() {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
}

/// Attempts at removing a staging folder that a worker is still writing into: 50 (2 ms apart,
/// 0.1 s at most). After the rename a worker can only finish a file it had already opened.
const REMOVE_ATTEMPTS: usize = 50;

fn untrack(path: &Path) {
    let mut unpublished = lock(&UNPUBLISHED);
    if let Some(i) = unpublished.iter().position(|p| p == path) {
        unpublished.swap_remove(i);
    }
}

/// What [`remove_unpublished`] did. While it lives, nothing is published and no temporary
/// is created (both locks are held): keep it until the process exits.
#[must_use = "publishing resumes when this is dropped"]
pub struct PublishingStopped {
    removed: usize,
    _publishing: MutexGuard<'static, ()>,
    _unpublished: MutexGuard<'static, Vec<PathBuf>>,
}

impl PublishingStopped {
    /// How many temporary files and staging folders were deleted.
    pub fn removed(&self) -> usize {
        self.removed
    }
}

/// For a process that must stop at once (a second Ctrl-C): waits for a publication in
/// progress to finish, then deletes every temporary file and staging folder of this process
/// that is not published, so that exiting leaves only whole outputs. Call it right before
/// exiting and keep the result until then.
pub fn remove_unpublished() -> PublishingStopped {
    let publishing = lock(&PUBLISHING);
    let mut unpublished = lock(&UNPUBLISHED);
    let removed = unpublished.len();
    for path in unpublished.drain(..) {
        if path.is_dir() {
            remove_staging(&path);
        } else {
            let _ = fs::remove_file(&path);
        }
    }
    PublishingStopped { removed, _publishing: publishing, _unpublished: unpublished }
}

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

/// The file in every output folder kfuse publishes that lists the entries kfuse wrote there:
/// a later run into the same folder replaces exactly those and never touches anything else.
pub const MANIFEST: &str = ".kfuse-manifest.json";
/// Prefix of staging folders (followed by the process id), inside or beside the destination.
const STAGING_PREFIX: &str = ".kfuse-staging-";
const MANIFEST_FORMAT: &str = "kfuse-manifest";

/// Whether process `pid` is still running (Linux: `/proc/PID` exists). Where `/proc` is not
/// available every process counts as running, so no staging folder is ever taken for stale.
fn process_alive(pid: u32) -> bool {
    if !Path::new("/proc/self").exists() {
        return true;
    }
    Path::new(&format!("/proc/{pid}")).exists()
}

/// Removes the staging folders of killed kfuse runs in `dir`: folders named
/// `{STAGING_PREFIX}{pid}` (inside a destination) or `.{name}{STAGING_PREFIX}{pid}` (beside
/// one), and the `{legacy}{pid}` folders of earlier kfuse versions, whose process is gone.
/// Nothing named otherwise is touched.
fn remove_stale_staging(dir: &Path, legacy: Option<&str>) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let ours = name
            .rsplit_once(STAGING_PREFIX)
            .filter(|(head, _)| head.is_empty() || head.starts_with('.'))
            .map(|(_, pid)| pid);
        let pid = ours
            .or_else(|| legacy.and_then(|l| name.strip_prefix(l)))
            .and_then(|rest| rest.parse::<u32>().ok());
        let Some(pid) = pid else { continue };
        let is_dir = entry.file_type().map(|t| t.is_dir()).unwrap_or(false);
        if is_dir && pid != std::process::id() && !process_alive(pid) {
            let _ = fs::remove_dir_all(entry.path());
        }
    }
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

/// The entries a folder's manifest lists (empty when there is none or it is unreadable).
fn read_manifest(dir: &Path) -> Vec<String> {
    let Ok(text) = fs::read_to_string(dir.join(MANIFEST)) else { return Vec::new() };
    let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else { return Vec::new() };
    if value.get("format").and_then(|f| f.as_str()) != Some(MANIFEST_FORMAT) {
        return Vec::new();
    }
    value
        .get("files")
        .and_then(|f| f.as_array())
        .map(|files| {
            files
                .iter()
                .filter_map(|f| f.as_str())
                // Plain names only: a manifest never makes kfuse touch anything outside.
                .filter(|n| is_plain_name(n))
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

/// The entries of `dir` that earlier kfuse runs published there (its [`MANIFEST`]; empty when
/// there is none): a command reading its inputs from its own output folder can tell its
/// earlier outputs from the user's files.
pub fn written_by_kfuse(dir: &Path) -> Vec<String> {
    read_manifest(dir)
}

fn manifest_json(files: &[String]) -> String {
    let value = serde_json::json!({
        "format": MANIFEST_FORMAT,
        "about": "entries of this folder written by kfuse; the next kfuse run into this folder replaces them and keeps everything else",
        "files": files,
    });
    serde_json::to_string_pretty(&value).unwrap_or_default()
}

/// A single file or folder name: not empty, no separator, not `.` or `..`.
pub fn is_plain_name(name: &str) -> bool {
    !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.contains('\\')
        && !name.contains('\0')
}

/// A directory of outputs that becomes visible only when complete.
///
/// Files are created under [`StagedDir::path`], a staging folder on the destination's file
/// system, and published by [`StagedDir::commit`]:
///
/// * **new destination**: the staging folder is a hidden sibling and is renamed to the
///   destination in one step;
/// * **existing destination** (a reused `--out`, or a mount point): the staging folder is
///   inside it; commit moves each staged entry in (a rename within one file system), removes
///   the entries the previous run listed in the folder's [`MANIFEST`] that this run did not
///   write, and refuses (before moving anything) when a staged name is taken by an entry kfuse
///   did not write. Nothing else in the folder is ever touched.
///
/// The destination is checked when staging starts (before any work): a file in its place is
/// refused. Staging folders of killed runs are removed then too. Dropped without commit (an
/// error, Ctrl-C), the staging folder and everything in it is deleted.
#[derive(Debug)]
pub struct StagedDir {
    staging: PathBuf,
    destination: PathBuf,
    inside: bool,
    committed: bool,
}

impl StagedDir {
    /// Starts staging outputs for `destination`.
    pub fn new(destination: &Path) -> Result<Self, GeometryError> {
        let refuse =
            |message: String| GeometryError::Format { path: destination.to_path_buf(), message };
        match fs::metadata(destination) {
            Ok(m) if !m.is_dir() => {
                return Err(refuse(
                    "exists and is not a folder; give a folder for the outputs (it is created if missing)".into(),
                ));
            }
            Ok(_) => {
                remove_stale_staging(destination, None);
                let staging = destination.join(format!("{STAGING_PREFIX}{}", std::process::id()));
                if staging.exists() {
                    fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
                }
                track_created(&staging, || fs::create_dir(&staging)).map_err(io_err(&staging))?;
                return Ok(Self {
                    staging,
                    destination: destination.to_path_buf(),
                    inside: true,
                    committed: false,
                });
            }
            Err(_) => {}
        }
        let parent = match destination.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).map_err(io_err(&parent))?;
        let name = destination
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let prefix = format!(".{name}{STAGING_PREFIX}");
        remove_stale_staging(&parent, Some(&format!(".{name}.partial-")));
        let staging = parent.join(format!("{prefix}{}", std::process::id()));
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
        }
        track_created(&staging, || fs::create_dir_all(&staging)).map_err(io_err(&staging))?;
        Ok(Self {
            staging,
            destination: destination.to_path_buf(),
            inside: false,
            committed: false,
        })
    }

    /// Refuses, before any work, when one of `names` (the entries this run may write) is
    /// taken in an existing destination by an entry kfuse did not write (not listed in its
    /// [`MANIFEST`]): [`StagedDir::commit`] would refuse the same after the work.
    pub fn refuse_foreign(&self, names: &[String]) -> Result<(), GeometryError> {
        if !self.inside {
            return Ok(());
        }
        let old = read_manifest(&self.destination);
        for name in names {
            let target = self.destination.join(name);
            if fs::symlink_metadata(&target).is_ok() && !old.contains(name) {
                return Err(foreign_entry(&self.destination, target));
            }
        }
        Ok(())
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

    fn staged_names(&self) -> Result<Vec<String>, GeometryError> {
        let mut names = Vec::new();
        for entry in fs::read_dir(&self.staging).map_err(io_err(&self.staging))? {
            let entry = entry.map_err(io_err(&self.staging))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if name != MANIFEST {
                names.push(name);
            }
        }
        names.sort();
        Ok(names)
    }

    /// Publishes the staged entries (see the type's docs) and returns the destination.
    pub fn commit(self) -> Result<PathBuf, GeometryError> {
        self.publish(false)
    }

    /// [`StagedDir::commit`] for outputs that accumulate over runs (`kfuse undistort` of the
    /// colour, then of the depth images into one folder): the entries earlier runs wrote stay
    /// (an entry of the same name is replaced) and the [`MANIFEST`] lists them all.
    pub fn commit_adding(self) -> Result<PathBuf, GeometryError> {
        self.publish(true)
    }

    fn publish(mut self, keep_previous: bool) -> Result<PathBuf, GeometryError> {
        let _publishing = lock(&PUBLISHING);
        let names = self.staged_names()?;
        if !self.inside {
            write_bytes_atomic(&self.staging.join(MANIFEST), manifest_json(&names).as_bytes())?;
            match fs::rename(&self.staging, &self.destination) {
                Ok(()) => {
                    self.committed = true;
                    return Ok(self.destination.clone());
                }
                // The destination appeared meanwhile: publish into it like a reused folder.
                Err(_) if self.destination.is_dir() => {}
                Err(e) => return Err(io_err(&self.destination)(e)),
            }
        }
        let dest = self.destination.clone();
        let old = read_manifest(&dest);
        // Refuse before moving anything when a name is taken by something kfuse did not write.
        for name in &names {
            let target = dest.join(name);
            if fs::symlink_metadata(&target).is_ok() && !old.contains(name) {
                return Err(foreign_entry(&dest, target));
            }
        }
        // The manifest first lists old and new entries, so a run killed during the moves
        // leaves every kfuse entry known to the next run.
        let mut union: Vec<String> = old.iter().chain(&names).cloned().collect();
        union.sort();
        union.dedup();
        write_bytes_atomic(&dest.join(MANIFEST), manifest_json(&union).as_bytes())?;
        for name in &old {
            if keep_previous || names.contains(name) {
                continue;
            }
            let stale = dest.join(name);
            match fs::symlink_metadata(&stale) {
                Ok(m) if m.is_dir() => fs::remove_dir_all(&stale).map_err(io_err(&stale))?,
                Ok(_) => fs::remove_file(&stale).map_err(io_err(&stale))?,
                Err(_) => {}
            }
        }
        for name in &names {
            let target = dest.join(name);
            if fs::symlink_metadata(&target).map(|m| m.is_dir()).unwrap_or(false) {
                fs::remove_dir_all(&target).map_err(io_err(&target))?;
            }
            fs::rename(self.staging.join(name), &target).map_err(io_err(&target))?;
        }
        let listed = if keep_previous { &union } else { &names };
        write_bytes_atomic(&dest.join(MANIFEST), manifest_json(listed).as_bytes())?;
        fs::remove_dir_all(&self.staging).map_err(io_err(&self.staging))?;
        self.committed = true;
        Ok(dest)
    }
}

/// The error for `target`, an entry in `dest` with an output's name that kfuse did not write.
fn foreign_entry(dest: &Path, target: PathBuf) -> GeometryError {
    GeometryError::Format {
        path: target,
        message: format!(
            "exists and was not written by kfuse (it is not listed in {}); move it away or choose another output folder",
            dest.join(MANIFEST).display()
        ),
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.staging);
        }
        untrack(&self.staging);
    }
}

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

/// Removes `{prefix}{pid}` files of processes that are gone.
fn remove_stale_files(dir: &Path, prefix: &str) {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kfuse-atomic-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// `/dev/null` given as an output: refused with a line naming it, before anything is
    /// written, by both writers; it stays a character device (a rename over it would have
    /// replaced it with a plain file, as it did to `/dev/full` in a user's trial).
    #[cfg(unix)]
    #[test]
    fn a_device_is_refused_and_left_alone() {
        use std::os::unix::fs::FileTypeExt;
        let null = Path::new("/dev/null");
        if !fs::metadata(null).is_ok_and(|m| m.file_type().is_char_device()) {
            println!("SKIP a_device_is_refused_and_left_alone: no /dev/null character device");
            return;
        }
        let err = write_bytes_atomic(null, b"x").unwrap_err().to_string();
        assert!(err.contains("/dev/null") && err.contains("not a regular file"), "{err}");
        let err = StagedFiles::new().add(null, b"x").unwrap_err().to_string();
        assert!(err.contains("not a regular file"), "{err}");
        assert!(fs::metadata(null).unwrap().file_type().is_char_device());
    }

    /// A symbolic link as an output is written through: the link stays a link, the file it
    /// points to gets the new content; a link to nothing is refused.
    #[cfg(unix)]
    #[test]
    fn a_link_is_written_through() {
        let dir = scratch("link");
        let (target, link) = (dir.join("real.json"), dir.join("link.json"));
        fs::write(&target, b"old").unwrap();
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_bytes_atomic(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(fs::read(&target).unwrap(), b"new");
        let mut files = StagedFiles::new();
        files.add(&link, b"newer").unwrap();
        files.commit().unwrap();
        assert!(fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        assert_eq!(fs::read(&target).unwrap(), b"newer");
        let dangling = dir.join("dangling.json");
        std::os::unix::fs::symlink(dir.join("missing.json"), &dangling).unwrap();
        let err = write_bytes_atomic(&dangling, b"x").unwrap_err().to_string();
        assert!(err.contains("link to a missing file"), "{err}");
        let mut names: Vec<String> = fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["dangling.json", "link.json", "real.json"], "temporary file left");
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
        // The writer's own failure comes back as an I/O error naming the target file.
        match err {
            Err(GeometryError::Io { path: p, source }) => {
                assert_eq!(p, path);
                assert_eq!(source.to_string(), "disk full");
            }
            other => panic!("{other:?}"),
        }
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

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    fn publish(dest: &Path, files: &[&str]) -> Result<PathBuf, GeometryError> {
        let staged = StagedDir::new(dest)?;
        for f in files {
            fs::write(staged.join(f), f).unwrap();
        }
        staged.commit()
    }

    #[test]
    fn reused_folder_ends_with_exactly_this_runs_files_and_keeps_the_users() {
        let dir = scratch("reuse");
        let dest = dir.join("out");
        publish(&dest, &["a.png", "b.png", "summary.json"]).unwrap();
        assert_eq!(names(&dest), [MANIFEST, "a.png", "b.png", "summary.json"]);
        fs::write(dest.join("notes.txt"), "mine").unwrap();
        publish(&dest, &["a.png", "summary.json"]).unwrap();
        // b.png (kfuse's, from the earlier run) is gone; the user's notes.txt is kept.
        assert_eq!(names(&dest), [MANIFEST, "a.png", "notes.txt", "summary.json"]);
        assert_eq!(read_manifest(&dest), ["a.png", "summary.json"]);
        assert_eq!(fs::read_to_string(dest.join("notes.txt")).unwrap(), "mine");
        assert_eq!(names(&dir), ["out"], "staging folder left behind");
    }

    #[test]
    fn commit_adding_keeps_the_earlier_runs_files() {
        let dir = scratch("adding");
        let dest = dir.join("out");
        publish(&dest, &["Colour_rect.tif"]).unwrap();
        fs::write(dest.join("notes.txt"), "mine").unwrap();
        let staged = StagedDir::new(&dest).unwrap();
        for f in ["Depth_rect.tif", "Colour_rect.tif"] {
            fs::write(staged.join(f), "second").unwrap();
        }
        staged.commit_adding().unwrap();
        assert_eq!(names(&dest), [MANIFEST, "Colour_rect.tif", "Depth_rect.tif", "notes.txt"]);
        assert_eq!(read_manifest(&dest), ["Colour_rect.tif", "Depth_rect.tif"]);
        assert_eq!(fs::read_to_string(dest.join("Colour_rect.tif")).unwrap(), "second");
        // A plain commit afterwards removes what it did not write again.
        publish(&dest, &["Depth_rect.tif"]).unwrap();
        assert_eq!(names(&dest), [MANIFEST, "Depth_rect.tif", "notes.txt"]);
    }

    #[test]
    fn a_users_entry_with_an_output_name_is_kept_and_the_run_refused() {
        let dir = scratch("clash");
        let dest = dir.join("out");
        fs::create_dir_all(dest.join("summary.json")).unwrap();
        fs::write(dest.join("summary.json/precious.txt"), "x").unwrap();
        let err = publish(&dest, &["a.png", "summary.json"]).unwrap_err().to_string();
        assert!(err.contains("summary.json") && err.contains("not written by kfuse"), "{err}");
        assert_eq!(names(&dest), ["summary.json"], "nothing may be published on refusal");
        assert_eq!(fs::read_to_string(dest.join("summary.json/precious.txt")).unwrap(), "x");
    }

    #[test]
    fn a_file_as_destination_is_refused_before_any_work() {
        let dir = scratch("file");
        let dest = dir.join("out");
        fs::write(&dest, "a file").unwrap();
        let err = StagedDir::new(&dest).unwrap_err().to_string();
        assert!(err.contains("not a folder"), "{err}");
        assert_eq!(fs::read_to_string(&dest).unwrap(), "a file");
        assert_eq!(names(&dir), ["out"]);
    }

    #[test]
    fn staging_of_killed_runs_is_removed_and_live_ones_kept() {
        let dir = scratch("stale");
        let dest = dir.join("out");
        // A pid above the kernel's pid_max (4194304) can never be alive.
        let dead = 4_194_305 + std::process::id() % 1000;
        for stale in [format!(".out{STAGING_PREFIX}{dead}"), format!(".out.partial-{dead}")] {
            fs::create_dir_all(dir.join(&stale)).unwrap();
            fs::write(dir.join(&stale).join("cloud.ply"), "half").unwrap();
        }
        // A folder of another (living) process and a user's look-alike are kept.
        let live = format!(".out{STAGING_PREFIX}1");
        fs::create_dir_all(dir.join(&live)).unwrap();
        fs::create_dir_all(dir.join(".out.partial-mine")).unwrap();
        publish(&dest, &["a.png"]).unwrap();
        assert_eq!(names(&dir), [live.as_str(), ".out.partial-mine", "out"]);
        // Inside an existing folder (the mount-point case) the same.
        fs::create_dir_all(dest.join(format!("{STAGING_PREFIX}{dead}"))).unwrap();
        publish(&dest, &["a.png"]).unwrap();
        assert_eq!(names(&dest), [MANIFEST, "a.png"]);
    }

    #[test]
    fn a_killed_writes_temporary_is_removed_when_the_file_is_written_again() {
        let dir = scratch("stale-tmp");
        let dead = 4_194_305 + std::process::id() % 1000;
        fs::write(dir.join(format!(".rig.json.partial-{dead}")), "half").unwrap();
        // Kept: a living process's temporary (pid 1), another file's, a user's look-alike.
        for keep in
            [".rig.json.partial-1", &format!(".g.json.partial-{dead}"), ".rig.json.partial-x"]
        {
            fs::write(dir.join(keep), "keep").unwrap();
        }
        write_bytes_atomic(&dir.join("rig.json"), b"{}").unwrap();
        let mut want = vec![
            format!(".g.json.partial-{dead}"),
            ".rig.json.partial-1".to_string(),
            ".rig.json.partial-x".to_string(),
            "rig.json".to_string(),
        ];
        want.sort();
        assert_eq!(names(&dir), want);
    }

    #[test]
    fn staged_files_appear_together_or_not_at_all() {
        let dir = scratch("files");
        let (a, b) = (dir.join("rig.json"), dir.join("rig.yaml"));
        {
            let mut staged = StagedFiles::new();
            staged.add(&a, b"{}").unwrap();
            staged.add(&b, b"%YAML").unwrap();
            // dropped: an error happened before commit
        }
        assert!(names(&dir).is_empty(), "{:?}", names(&dir));
        let mut staged = StagedFiles::new();
        staged.add(&a, b"{}").unwrap();
        staged.add(&b, b"%YAML").unwrap();
        staged.commit().unwrap();
        assert_eq!(names(&dir), ["rig.json", "rig.yaml"]);
    }
}
