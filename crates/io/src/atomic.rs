//! Outputs that appear whole or not at all.
//!
//! Every file kfuse writes goes first to a hidden temporary name in the same directory and is
//! renamed into place when complete (a rename within one directory is atomic on POSIX), so a
//! crash, a full disk or a bad input never leaves a truncated file behind. Multi-file outputs
//! use [`StagedDir`]: all files are written into a hidden staging directory beside the
//! destination and published only by [`StagedDir::commit`] (one directory rename for a new
//! folder; an existing folder is replaced as a whole: old aside, new in, old removed, so a
//! killed run leaves the old folder or the new one, never a mixture); dropping it uncommitted
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
/// * **existing destination** (a reused `--out`): the staging folder is a hidden sibling too,
///   and the folder is replaced as a whole. Commit carries into the staging folder, as hard
///   links, every entry that stays (the user's files, and with [`StagedDir::commit_adding`]
///   the earlier runs' outputs), then renames the old folder aside
///   (`.NAME.kfuse-replaced-PID`), renames the new one in, and removes the old one. A run
///   killed at any moment leaves the old folder or the new one complete: killed before the
///   first rename, the old folder is untouched (the staging folder is removed by the next
///   run); between the renames, the next run into the same destination puts the old folder
///   back; after them, it removes the old one. Entries the previous run listed in the folder's
///   [`MANIFEST`] that this run did not write are not carried (they disappear), and commit
///   refuses (before changing anything) when a staged name is taken by an entry kfuse did not
///   write. Nothing of the user's is ever lost or changed;
/// * **existing destination that cannot be replaced** (a mount point, the working folder of
///   the process or a folder holding it, a parent folder kfuse may not write, a file system
///   without hard links, a file kfuse may not link): the
///   staging folder is inside it and commit moves each staged entry in, one by one (a kill in
///   the middle leaves a mixture, which the manifest lets the next run replace); the same
///   refusal and removal of earlier entries.
///
/// The destination is checked when staging starts (before any work): a file in its place is
/// refused. Staging folders of killed runs are removed then too. Dropped without commit (an
/// error, Ctrl-C), the staging folder and everything in it is deleted.
#[derive(Debug)]
pub struct StagedDir {
    staging: PathBuf,
    destination: PathBuf,
    mode: Mode,
    committed: bool,
}

/// How a [`StagedDir`] publishes.
#[derive(Debug, Clone, PartialEq)]
enum Mode {
    /// The destination did not exist: one rename of the sibling staging folder.
    New,
    /// The destination exists (the real folder, links resolved): replaced as a whole by the
    /// sibling staging folder.
    Replace(PathBuf),
    /// The destination exists and cannot be replaced: staging inside, entries moved one by one.
    InPlace,
}

/// Middle of the name of an old output folder renamed aside while its replacement is renamed
/// in (`.NAME.kfuse-replaced-PID`, beside it).
const REPLACED_PREFIX: &str = ".kfuse-replaced-";

/// Environment variable naming a point of [`StagedDir::commit`] at which the process exits
/// at once, as if killed (no destructor runs, nothing is cleaned up): `carried` (the staging
/// folder is complete, the old folder untouched), `aside` (the old folder renamed aside, the
/// new one not yet in), `swapped` (the new folder in, the old one not yet removed). For the
/// tests of what a killed run leaves; never set it otherwise.
pub const KILL_AT_ENV: &str = "KFUSE_TEST_KILL_AT";

/// Exit status of the [`KILL_AT_ENV`] hook: a process killed by SIGKILL (128 + 9).
const KILLED_EXIT: i32 = 137;

/// Exits the process at once when [`KILL_AT_ENV`] names `point`.
fn kill_point(point: &str) {
    if std::env::var_os(KILL_AT_ENV).is_some_and(|v| v == point) {
        std::process::exit(KILLED_EXIT);
    }
}

/// `.{name}{middle}{pid}` beside `path`: the hidden siblings of an output folder.
fn sibling(path: &Path, middle: &str, pid: u32) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!(".{name}{middle}{pid}"))
}

/// Finishes what a killed replacement of `destination` left (see [`StagedDir`]): an old folder
/// renamed aside by a process that is gone is put back when `destination` is missing (the new
/// one never came in), and removed otherwise (the new one is in place).
fn recover_replaced(destination: &Path) {
    let (Some(parent), Some(name)) = (destination.parent(), destination.file_name()) else {
        return;
    };
    let parent = if parent.as_os_str().is_empty() { Path::new(".") } else { parent };
    let prefix = format!(".{}{REPLACED_PREFIX}", name.to_string_lossy());
    let Ok(entries) = fs::read_dir(parent) else { return };
    for entry in entries.flatten() {
        let entry_name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = entry_name.strip_prefix(&prefix).and_then(|p| p.parse::<u32>().ok()) else {
            continue;
        };
        let is_dir = entry.file_type().map(|t| t.is_dir()).unwrap_or(false);
        if !is_dir || pid == std::process::id() || process_alive(pid) {
            continue;
        }
        if fs::symlink_metadata(destination).is_err() {
            let _ = fs::rename(entry.path(), destination);
        } else {
            let _ = fs::remove_dir_all(entry.path());
        }
    }
}

/// The real folder behind an existing `destination` when it can be replaced as a whole: not
/// the working folder of this process nor a folder holding it (the shell that started kfuse
/// would be left in a deleted folder), not a mount point (its parent is on the same file
/// system), and a parent that exists. `None`: publish in place.
fn replaceable(destination: &Path) -> Option<PathBuf> {
    let real = fs::canonicalize(destination).ok()?;
    let cwd = std::env::current_dir().ok().and_then(|c| fs::canonicalize(c).ok());
    if cwd.is_some_and(|c| c.starts_with(&real)) {
        return None;
    }
    let parent = real.parent()?;
    same_file_system(parent, &real).then_some(real)
}

/// Whether `a` and `b` are on one file system (a rename between them can work).
#[cfg(unix)]
fn same_file_system(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (fs::metadata(a), fs::metadata(b)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev(),
        _ => false,
    }
}

/// Without device numbers to compare, no folder is taken for replaceable.
#[cfg(not(unix))]
fn same_file_system(_: &Path, _: &Path) -> bool {
    false
}

/// Swaps two folders in one step (`renameat2(2)` with `RENAME_EXCHANGE`, Linux 3.15 and
/// the common file systems: ext4, XFS, Btrfs, tmpfs, overlayfs): there is no moment at which
/// either name is missing. An error where the kernel or file system has no such exchange.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use nix::fcntl::{AT_FDCWD, RenameFlags, renameat2};
    renameat2(AT_FDCWD, a, AT_FDCWD, b, RenameFlags::RENAME_EXCHANGE).map_err(std::io::Error::from)
}

/// Without `renameat2`, no exchange: the caller renames twice.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::Error::new(std::io::ErrorKind::Unsupported, "no atomic exchange of folders"))
}

/// Makes `to` a copy of the entry `from` that shares its data: a hard link of a file (or link,
/// pipe, socket: linked as it is, not followed), a new folder with its permissions holding such
/// copies of its entries. Nothing at `from` changes.
fn link_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    let meta = fs::symlink_metadata(from)?;
    if !meta.is_dir() {
        return fs::hard_link(from, to);
    }
    fs::create_dir(to)?;
    for entry in fs::read_dir(from)? {
        let entry = entry?;
        link_tree(&entry.path(), &to.join(entry.file_name()))?;
    }
    keep_owner(&meta, to)?;
    fs::set_permissions(to, meta.permissions())
}

/// Gives the new folder `to` the owner and group of the folder it copies (`meta`): a re-run
/// as root made the user's own subfolders root-owned. Changing the owner needs the rights to
/// (root, or the owner itself keeping its own uid); without them the folder is this user's,
/// as any file it creates. (ACLs and extended attributes are not copied.)
#[cfg(unix)]
fn keep_owner(meta: &fs::Metadata, to: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    let created = fs::symlink_metadata(to)?;
    if (created.uid(), created.gid()) == (meta.uid(), meta.gid()) {
        return Ok(());
    }
    match std::os::unix::fs::chown(to, Some(meta.uid()), Some(meta.gid())) {
        Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => Ok(()),
        other => other,
    }
}

#[cfg(not(unix))]
fn keep_owner(_: &fs::Metadata, _: &Path) -> std::io::Result<()> {
    Ok(())
}

impl StagedDir {
    /// Starts staging outputs for `destination`.
    pub fn new(destination: &Path) -> Result<Self, GeometryError> {
        let refuse =
            |message: String| GeometryError::Format { path: destination.to_path_buf(), message };
        recover_replaced(destination);
        match fs::metadata(destination) {
            Ok(m) if !m.is_dir() => {
                return Err(refuse(
                    "exists and is not a folder; give a folder for the outputs (it is created if missing)".into(),
                ));
            }
            Ok(_) => {
                remove_stale_staging(destination, None);
                if let Some(real) = replaceable(destination) {
                    recover_replaced(&real);
                    if let Ok(staged) =
                        Self::beside(&real, destination, Mode::Replace(real.clone()))
                    {
                        return Ok(staged);
                    }
                }
                let staging = destination.join(format!("{STAGING_PREFIX}{}", std::process::id()));
                if staging.exists() {
                    fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
                }
                track_created(&staging, || fs::create_dir(&staging)).map_err(io_err(&staging))?;
                return Ok(Self {
                    staging,
                    destination: destination.to_path_buf(),
                    mode: Mode::InPlace,
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
        Self::beside(destination, destination, Mode::New)
    }

    /// Staging in the hidden sibling of `folder` (`.NAME.kfuse-staging-PID`), after removing
    /// the staging folders of killed runs there.
    fn beside(folder: &Path, destination: &Path, mode: Mode) -> Result<Self, GeometryError> {
        let parent = match folder.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = folder
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        remove_stale_staging(&parent, Some(&format!(".{name}.partial-")));
        let staging = parent.join(format!(".{name}{STAGING_PREFIX}{}", std::process::id()));
        if staging.exists() {
            fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
        }
        track_created(&staging, || fs::create_dir_all(&staging)).map_err(io_err(&staging))?;
        Ok(Self { staging, destination: destination.to_path_buf(), mode, committed: false })
    }

    /// Refuses, before any work, when one of `names` (the entries this run may write) is
    /// taken in an existing destination by an entry kfuse did not write (not listed in its
    /// [`MANIFEST`]): [`StagedDir::commit`] would refuse the same after the work.
    pub fn refuse_foreign(&self, names: &[String]) -> Result<(), GeometryError> {
        if self.mode == Mode::New {
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

    /// Whether the destination existed when staging started, so that a commit replaces (or
    /// adds to) an earlier output. A run stopped early (Ctrl-C) should then not commit: its
    /// partial result would replace the earlier complete one.
    pub fn replaces_existing(&self) -> bool {
        self.mode != Mode::New
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
        if self.mode == Mode::New {
            write_bytes_atomic(&self.staging.join(MANIFEST), manifest_json(&names).as_bytes())?;
            match fs::rename(&self.staging, &self.destination) {
                Ok(()) => {
                    self.committed = true;
                    return Ok(self.destination.clone());
                }
                // The destination appeared meanwhile: replace it like a reused folder.
                Err(_) if self.destination.is_dir() => {
                    let _ = fs::remove_file(self.staging.join(MANIFEST));
                    self.mode = match replaceable(&self.destination) {
                        Some(real) => Mode::Replace(real),
                        None => Mode::InPlace,
                    };
                }
                Err(e) => return Err(io_err(&self.destination)(e)),
            }
        }
        let dest = self.destination.clone();
        let old = read_manifest(&dest);
        // Refuse before changing anything when a name is taken by something kfuse did not write.
        for name in &names {
            let target = dest.join(name);
            if fs::symlink_metadata(&target).is_ok() && !old.contains(name) {
                return Err(foreign_entry(&dest, target));
            }
        }
        if let Mode::Replace(real) = self.mode.clone() {
            match self.carry(&real, &names, &old, keep_previous) {
                Ok(carried) => return self.replace(&real, &names, &old, carried, keep_previous),
                // No hard links here (or a folder kfuse may not read): publish in place.
                Err(_) => self.uncarry(&names)?,
            }
        }
        self.move_in(&dest, &names, &old, keep_previous)
    }

    /// Links into the staging folder every entry of the old folder `real` that the new one
    /// keeps: the user's entries, and with `keep_previous` the earlier runs' outputs this run
    /// does not write again. Returns their names.
    fn carry(
        &self,
        real: &Path,
        names: &[String],
        old: &[String],
        keep_previous: bool,
    ) -> std::io::Result<Vec<String>> {
        let mut carried = Vec::new();
        for entry in fs::read_dir(real)? {
            let name = entry?.file_name().to_string_lossy().into_owned();
            let dropped = name == MANIFEST
                || name.contains(STAGING_PREFIX)
                || names.contains(&name)
                || (old.contains(&name) && !keep_previous);
            if !dropped {
                link_tree(&real.join(&name), &self.staging.join(&name))?;
                carried.push(name);
            }
        }
        carried.sort();
        Ok(carried)
    }

    /// Removes from the staging folder whatever [`StagedDir::carry`] linked in before it
    /// failed: everything but this run's `names`.
    fn uncarry(&self, names: &[String]) -> Result<(), GeometryError> {
        for entry in fs::read_dir(&self.staging).map_err(io_err(&self.staging))? {
            let entry = entry.map_err(io_err(&self.staging))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if names.contains(&name) {
                continue;
            }
            let path = entry.path();
            match fs::symlink_metadata(&path) {
                Ok(m) if m.is_dir() => fs::remove_dir_all(&path).map_err(io_err(&path))?,
                Ok(_) => fs::remove_file(&path).map_err(io_err(&path))?,
                Err(_) => {}
            }
        }
        Ok(())
    }

    /// Replaces the old folder `real` with the complete staging folder (see the type's docs).
    fn replace(
        &mut self,
        real: &Path,
        names: &[String],
        old: &[String],
        carried: Vec<String>,
        keep_previous: bool,
    ) -> Result<PathBuf, GeometryError> {
        let listed: Vec<String> = if keep_previous {
            let mut l: Vec<String> =
                names.iter().chain(carried.iter().filter(|c| old.contains(c))).cloned().collect();
            l.sort();
            l.dedup();
            l
        } else {
            names.to_vec()
        };
        write_bytes_atomic(&self.staging.join(MANIFEST), manifest_json(&listed).as_bytes())?;
        if let Ok(m) = fs::metadata(real) {
            let _ = keep_owner(&m, &self.staging);
            let _ = fs::set_permissions(&self.staging, m.permissions());
        }
        kill_point("carried");
        let aside = sibling(real, REPLACED_PREFIX, std::process::id());
        if exchange(&self.staging, real).is_ok() {
            // One atomic step: the new folder is at `real`, the old one where the staging
            // folder was (a run killed now leaves the new folder complete, and the old one
            // under a staging name that the next run removes).
            self.committed = true;
            kill_point("exchanged");
            if fs::rename(&self.staging, &aside).is_err() {
                // The new folder is in: the old one goes, wherever it is (a staging name is
                // removed by the next run if this fails too).
                let _ = fs::remove_dir_all(&self.staging);
                return Ok(self.destination.clone());
            }
        } else {
            // No atomic exchange on this file system: two renames, between which `real` is
            // missing until the next run puts the old folder back (`recover_replaced`).
            fs::rename(real, &aside).map_err(io_err(real))?;
            kill_point("aside");
            if let Err(e) = fs::rename(&self.staging, real) {
                let _ = fs::rename(&aside, real);
                return Err(io_err(real)(e));
            }
            self.committed = true;
        }
        kill_point("swapped");
        // An entry created in the old folder while this ran (by another program) is moved over.
        if let Ok(entries) = fs::read_dir(&aside) {
            for entry in entries.flatten() {
                let name = entry.file_name().to_string_lossy().into_owned();
                let known = name == MANIFEST
                    || name.contains(STAGING_PREFIX)
                    || carried.contains(&name)
                    || old.contains(&name)
                    || names.contains(&name);
                if !known && fs::symlink_metadata(real.join(&name)).is_err() {
                    let _ = fs::rename(entry.path(), real.join(&name));
                }
            }
        }
        fs::remove_dir_all(&aside).map_err(io_err(&aside))?;
        Ok(self.destination.clone())
    }

    /// Moves the staged entries into `dest` one by one (see the type's docs).
    fn move_in(
        &mut self,
        dest: &Path,
        names: &[String],
        old: &[String],
        keep_previous: bool,
    ) -> Result<PathBuf, GeometryError> {
        // The manifest first lists old and new entries, so a run killed during the moves
        // leaves every kfuse entry known to the next run.
        let mut union: Vec<String> = old.iter().chain(names).cloned().collect();
        union.sort();
        union.dedup();
        write_bytes_atomic(&dest.join(MANIFEST), manifest_json(&union).as_bytes())?;
        for name in old {
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
        for name in names {
            let target = dest.join(name);
            if fs::symlink_metadata(&target).map(|m| m.is_dir()).unwrap_or(false) {
                fs::remove_dir_all(&target).map_err(io_err(&target))?;
            }
            fs::rename(self.staging.join(name), &target).map_err(io_err(&target))?;
        }
        let listed = if keep_previous { &union } else { names };
        write_bytes_atomic(&dest.join(MANIFEST), manifest_json(listed).as_bytes())?;
        fs::remove_dir_all(&self.staging).map_err(io_err(&self.staging))?;
        self.committed = true;
        Ok(dest.to_path_buf())
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

    fn inode(p: &Path) -> u64 {
        use std::os::unix::fs::MetadataExt;
        fs::metadata(p).unwrap().ino()
    }

    /// A reused folder is replaced as a whole (a new folder, not files moved one by one into
    /// the old one, which a kill in the middle left half old, half new): the earlier run's
    /// outputs that this run does not write are gone, the user's file and folder are in the new
    /// folder unchanged (the same data, linked), nothing is left beside it.
    #[cfg(unix)]
    #[test]
    fn a_reused_folder_is_replaced_as_a_whole_with_the_users_entries() {
        let dir = scratch("replace");
        let dest = dir.join("out");
        publish(&dest, &["a.png", "b.png", "summary.json"]).unwrap();
        fs::write(dest.join("notes.txt"), "mine").unwrap();
        fs::create_dir(dest.join("mine")).unwrap();
        fs::write(dest.join("mine/x.txt"), "x").unwrap();
        let (before, notes) = (inode(&dest), inode(&dest.join("notes.txt")));
        publish(&dest, &["a.png", "summary.json"]).unwrap();
        assert_ne!(inode(&dest), before, "the old folder was changed in place, not replaced");
        assert_eq!(names(&dest), [MANIFEST, "a.png", "mine", "notes.txt", "summary.json"]);
        assert_eq!(fs::read_to_string(dest.join("a.png")).unwrap(), "a.png");
        assert_eq!(inode(&dest.join("notes.txt")), notes, "the user's file must be the same file");
        assert_eq!(fs::read_to_string(dest.join("mine/x.txt")).unwrap(), "x");
        assert_eq!(read_manifest(&dest), ["a.png", "summary.json"]);
        assert_eq!(names(&dir), ["out"], "old folder or staging left beside it");
    }

    /// What a replacement killed between its two renames leaves (the old folder aside, the
    /// new one complete in its staging folder, no destination): the next run into the
    /// destination puts the old folder back before it starts; killed after them (the new
    /// folder in, the old one aside), the next run removes the old one.
    #[test]
    fn a_killed_replacement_is_finished_by_the_next_run() {
        let dir = scratch("replace-killed");
        let dest = dir.join("out");
        let dead = 4_194_305 + std::process::id() % 1000;
        publish(&dest, &["a.png", "b.png", "summary.json"]).unwrap();
        let aside = dir.join(format!(".out{REPLACED_PREFIX}{dead}"));
        let staging = dir.join(format!(".out{STAGING_PREFIX}{dead}"));
        fs::rename(&dest, &aside).unwrap();
        fs::create_dir(&staging).unwrap();
        fs::write(staging.join("a.png"), "new").unwrap();
        let staged = StagedDir::new(&dest).unwrap();
        assert_eq!(names(&dest), [MANIFEST, "a.png", "b.png", "summary.json"], "old not back");
        assert_eq!(fs::read_to_string(dest.join("a.png")).unwrap(), "a.png");
        drop(staged);
        assert_eq!(names(&dir), ["out"]);
        // Killed after the renames: the new folder is in place, the old one aside.
        fs::create_dir(&aside).unwrap();
        fs::write(aside.join("b.png"), "old").unwrap();
        publish(&dest, &["c.png"]).unwrap();
        assert_eq!(names(&dest), [MANIFEST, "c.png"]);
        assert_eq!(names(&dir), ["out"], "the old folder of the killed run was left");
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
