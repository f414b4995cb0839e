//! Output folders published whole: new, replaced as a whole, or (where a folder cannot be
//! replaced) moved in under a journal.

use super::in_place;
use super::*;

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
///   without hard links, a file kfuse may not link): the staging folder is inside it and
///   commit moves the entries in one by one under a journal (`in_place`): the old entries
///   leave into a hidden folder, the new ones come in, and a run killed in the middle is
///   finished by the next kfuse run into the folder before it starts, so the mixture of a
///   killed run never stays; an error undoes the moves. The same refusal of foreign entries.
///
/// The destination is checked when staging starts (before any work): a file in its place is
/// refused. Staging folders of killed runs are removed then too. Dropped without commit (an
/// error, Ctrl-C), the staging folder and everything in it is deleted.
#[derive(Debug)]
pub struct StagedDir {
    pub(super) staging: PathBuf,
    destination: PathBuf,
    mode: Mode,
    pub(super) committed: bool,
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
pub(super) const REPLACED_PREFIX: &str = ".kfuse-replaced-";

/// Environment variable naming a point of [`StagedDir::commit`] at which the process exits
/// at once, as if killed (no destructor runs, nothing is cleaned up): `carried` (the staging
/// folder is complete, the old folder untouched), `aside` (the old folder renamed aside, the
/// new one not yet in), `swapped` (the new folder in, the old one not yet removed). For the
/// tests of what a killed run leaves; never set it otherwise.
pub const KILL_AT_ENV: &str = "KFUSE_TEST_KILL_AT";

/// Exit status of the [`KILL_AT_ENV`] hook: a process killed by SIGKILL (128 + 9).
const KILLED_EXIT: i32 = 137;

/// Exits the process at once when [`KILL_AT_ENV`] names `point`.
pub(super) fn kill_point(point: &str) {
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
                in_place::finish_interrupted(destination)?;
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
