//! What this process has created and not yet published, for removal when it must stop at once.

use super::*;

/// Temporary files and staging folders of this process that are neither published nor
/// removed yet: what [`remove_unpublished`] deletes when the process must stop at once.
static UNPUBLISHED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Held while staged outputs are published, so that [`remove_unpublished`] never runs in the
/// middle of a publication of several files.
pub(super) static PUBLISHING: Mutex<()> = Mutex::new(());

/// Creates `path` with `create` and records it as unpublished, both under the lock that
/// [`remove_unpublished`] takes and keeps until the process exits: either the removal sees the
/// new path, or it ran first and this waits (until exit), so nothing is created behind its
/// back. (Recording first and creating after left a staging folder behind when the second
/// Ctrl-C came in between.)
pub(super) fn track_created<T>(
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

pub(super) fn untrack(path: &Path) {
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
