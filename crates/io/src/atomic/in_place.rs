//! Publication into an output folder that cannot be replaced as a whole (a mount point, the
//! working folder of the process: `--out .`), under a journal.
//!
//! The entries move in one by one, so for a moment the folder holds some old and some new
//! entries. What keeps that moment from becoming a result is a journal written (atomically)
//! into the folder before the first entry moves and removed after the last: it names the
//! old entries that go (moved into a hidden `.kfuse-previous-PID` folder, not deleted, until
//! the end), the new ones that come in (from the staging folder) and the manifest that ends
//! it. A run killed while the journal exists is finished by the next kfuse run into the same
//! folder, before that run does anything else ([`finish_interrupted`]): every step checks
//! where its entry is, so the publication can be finished from any point. An error inside
//! the running process (a rename refused) undoes the steps taken instead, and the old
//! output is back as it was.

use super::staged_dir::kill_point;
use super::*;

/// The journal of an in-place publication, inside the destination.
pub(super) const JOURNAL: &str = ".kfuse-publishing.json";
/// Prefix of the folder inside the destination that holds the old entries while the new
/// ones move in (followed by the process id).
pub(super) const PREVIOUS_PREFIX: &str = ".kfuse-previous-";
/// `format` of the journal.
const JOURNAL_FORMAT: &str = "kfuse-publishing";
/// Largest journal read back (checked before reading): it lists entry names of one folder;
/// 16 MiB holds about 200 000 of them, far beyond any kfuse output's top level (a sequence
/// has a few dozen), and a foreign or damaged file of any size costs at most this much.
const JOURNAL_MAX_BYTES: u64 = 16 << 20;

/// What one in-place publication does, as written in [`JOURNAL`].
#[derive(Debug, Clone, PartialEq)]
struct Journal {
    /// The publishing process.
    pid: u32,
    /// The staging folder's name inside the destination.
    staging: String,
    /// The folder's name inside the destination that the outgoing entries move into.
    previous: String,
    /// The manifest's entries before the publication (restored by an undo).
    old: Vec<String>,
    /// Entries of the old output that leave (moved into `previous`).
    outgoing: Vec<String>,
    /// Entries of the new output (moved in from `staging`).
    incoming: Vec<String>,
    /// The manifest's entries once published.
    manifest: Vec<String>,
}

impl Journal {
    fn to_json(&self) -> String {
        let value = serde_json::json!({
            "format": JOURNAL_FORMAT,
            "about": "a kfuse run was publishing its outputs into this folder; the next kfuse run into it finishes the publication",
            "pid": self.pid,
            "staging": self.staging,
            "previous": self.previous,
            "old": self.old,
            "outgoing": self.outgoing,
            "incoming": self.incoming,
            "manifest": self.manifest,
        });
        serde_json::to_string_pretty(&value).unwrap_or_default()
    }

    /// The journal in `dest`, when there is one that kfuse wrote: bounded in size, every name
    /// a plain name, the two folders named as kfuse names them. Anything else is `None` (a
    /// journal never makes kfuse touch anything outside the folder).
    fn read(dest: &Path) -> Option<Self> {
        let path = dest.join(JOURNAL);
        let meta = fs::symlink_metadata(&path).ok()?;
        if !meta.is_file() || meta.len() > JOURNAL_MAX_BYTES {
            return None;
        }
        let value: serde_json::Value =
            serde_json::from_str(&fs::read_to_string(&path).ok()?).ok()?;
        if value.get("format")?.as_str()? != JOURNAL_FORMAT {
            return None;
        }
        let names = |key: &str| -> Option<Vec<String>> {
            value
                .get(key)?
                .as_array()?
                .iter()
                .map(|n| n.as_str().filter(|n| is_plain_name(n)).map(str::to_string))
                .collect()
        };
        let folder = |key: &str, prefix: &str| -> Option<String> {
            let name = value.get(key)?.as_str()?;
            (is_plain_name(name) && name.starts_with(prefix)).then(|| name.to_string())
        };
        Some(Self {
            pid: u32::try_from(value.get("pid")?.as_u64()?).ok()?,
            staging: folder("staging", STAGING_PREFIX)?,
            previous: folder("previous", PREVIOUS_PREFIX)?,
            old: names("old")?,
            outgoing: names("outgoing")?,
            incoming: names("incoming")?,
            manifest: names("manifest")?,
        })
    }
}

/// Whether anything (a file, a folder, a link) is at `path`, links not followed.
fn present(path: &Path) -> bool {
    fs::symlink_metadata(path).is_ok()
}

fn rename(from: &Path, to: &Path) -> Result<(), GeometryError> {
    fs::rename(from, to).map_err(io_err(to))
}

/// Sorted, without repeats.
fn union(a: &[String], b: &[String]) -> Vec<String> {
    let mut all: Vec<String> = a.iter().chain(b).cloned().collect();
    all.sort();
    all.dedup();
    all
}

/// Carries out `journal` in `dest` from wherever an earlier attempt stopped; the journal is
/// removed at the end, then the emptied folders.
fn roll_forward(dest: &Path, journal: &Journal) -> Result<(), GeometryError> {
    let staging = dest.join(&journal.staging);
    let previous = dest.join(&journal.previous);
    if !present(&previous) {
        fs::create_dir(&previous).map_err(io_err(&previous))?;
    }
    // While entries move, the manifest lists old and new: whatever happens, every kfuse entry
    // of the folder is known to the next run.
    let listed = union(&journal.old, &journal.incoming);
    write_bytes_atomic(&dest.join(MANIFEST), manifest_json(&listed).as_bytes())?;
    for name in &journal.outgoing {
        // An entry that also comes in is the old one only while its new one is still staged.
        let still_old = !journal.incoming.contains(name) || present(&staging.join(name));
        let (from, to) = (dest.join(name), previous.join(name));
        if still_old && present(&from) && !present(&to) {
            rename(&from, &to)?;
        }
    }
    for (i, name) in journal.incoming.iter().enumerate() {
        let from = staging.join(name);
        if present(&from) {
            rename(&from, &dest.join(name))?;
        }
        if i == 0 {
            kill_point("moving");
        }
    }
    write_bytes_atomic(&dest.join(MANIFEST), manifest_json(&journal.manifest).as_bytes())?;
    let journal_path = dest.join(JOURNAL);
    fs::remove_file(&journal_path).map_err(io_err(&journal_path))?;
    kill_point("published");
    fs::remove_dir_all(&previous).map_err(io_err(&previous))?;
    if present(&staging) {
        fs::remove_dir_all(&staging).map_err(io_err(&staging))?;
    }
    Ok(())
}

/// Undoes what [`roll_forward`] did of `journal` in this process: the new entries back into
/// the staging folder, the old ones back in place, the old manifest, no journal. Best effort:
/// every step that can be taken is taken.
fn roll_back(dest: &Path, journal: &Journal) {
    let staging = dest.join(&journal.staging);
    let previous = dest.join(&journal.previous);
    for name in journal.incoming.iter().rev() {
        let (at, back) = (dest.join(name), staging.join(name));
        if !present(&back) && present(&at) {
            let _ = fs::rename(&at, &back);
        }
    }
    for name in &journal.outgoing {
        let (aside, at) = (previous.join(name), dest.join(name));
        if present(&aside) && !present(&at) {
            let _ = fs::rename(&aside, &at);
        }
    }
    let _ = write_bytes_atomic(&dest.join(MANIFEST), manifest_json(&journal.old).as_bytes());
    let _ = fs::remove_file(dest.join(JOURNAL));
    let _ = fs::remove_dir(&previous);
}

/// Finishes the in-place publication into `dest` that a killed kfuse run left (its journal
/// names a process that is gone), and removes the `.kfuse-previous-PID` folders of gone
/// processes that no journal names (left by a run killed right before or after its
/// journal). Returns whether one was finished. Refused (nothing is changed) while another
/// running process publishes into `dest`, and when the killed run's publication cannot be
/// finished (a rename refused): the folder is left as it is, with its journal.
pub(super) fn finish_interrupted(dest: &Path) -> Result<bool, GeometryError> {
    let mut finished = false;
    let journal = Journal::read(dest);
    if let Some(j) = &journal
        && j.pid != std::process::id()
    {
        let refuse = |message: String| GeometryError::Format { path: dest.to_path_buf(), message };
        if process_alive(j.pid) {
            return Err(refuse(format!(
                "another kfuse run (process {}) is publishing its outputs into this folder; wait for it to end or choose another output folder",
                j.pid
            )));
        }
        roll_forward(dest, j).map_err(|e| {
            refuse(format!(
                "a killed kfuse run left its outputs half-published here and they could not be finished ({e}); see {JOURNAL} in it, or choose another output folder"
            ))
        })?;
        finished = true;
    }
    let Ok(entries) = fs::read_dir(dest) else { return Ok(finished) };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = name.strip_prefix(PREVIOUS_PREFIX).and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        let named =
            journal.as_ref().is_some_and(|j| j.previous == name) && present(&dest.join(JOURNAL));
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        if is_dir && !named && pid != std::process::id() && !process_alive(pid) {
            let _ = fs::remove_dir_all(entry.path());
        }
    }
    Ok(finished)
}

impl StagedDir {
    /// Publishes the staged `names` into `dest` in place, under a journal (see the module's
    /// docs): the entries of the old output (`old`, the manifest's) that this run writes again
    /// or drops (all of them but, with `keep_previous`, those it does not write) leave, the
    /// new ones come in.
    pub(super) fn move_in(
        &mut self,
        dest: &Path,
        names: &[String],
        old: &[String],
        keep_previous: bool,
    ) -> Result<PathBuf, GeometryError> {
        let file_name = |p: &Path| p.file_name().map(|n| n.to_string_lossy().into_owned());
        let staging = file_name(&self.staging).unwrap_or_default();
        let previous_name = format!("{PREVIOUS_PREFIX}{}", std::process::id());
        let previous = dest.join(&previous_name);
        if present(&previous) {
            fs::remove_dir_all(&previous).map_err(io_err(&previous))?;
        }
        let journal = Journal {
            pid: std::process::id(),
            staging,
            previous: previous_name,
            old: old.to_vec(),
            outgoing: old
                .iter()
                .filter(|o| (!keep_previous || names.contains(o)) && present(&dest.join(o)))
                .cloned()
                .collect(),
            incoming: names.to_vec(),
            manifest: if keep_previous { union(old, names) } else { names.to_vec() },
        };
        write_bytes_atomic(&dest.join(JOURNAL), journal.to_json().as_bytes())?;
        kill_point("journaled");
        match roll_forward(dest, &journal) {
            Ok(()) => {
                self.committed = true;
                Ok(dest.to_path_buf())
            }
            Err(e) => {
                roll_back(dest, &journal);
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::names;
    use super::*;

    fn strings(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    /// A journal as a killed run (a pid above the kernel's pid_max, never alive) leaves it at
    /// each step, old output {a, b, keep} with b dropped and a rewritten, new {a, c}: the
    /// next run's [`finish_interrupted`] ends with exactly the new output, the user's file,
    /// and nothing hidden but the manifest.
    #[test]
    fn a_killed_publication_is_finished_from_every_step() {
        let dead = 4_194_305 + std::process::id() % 1000;
        // Steps: 0 = journal written, nothing moved; 1 = old entries aside; 2 = `a` moved
        // in; 3 = all moved in; 4 = journal removed, folders not yet.
        for step in 0..5 {
            let dest = std::env::temp_dir()
                .join(format!("kfuse-in-place-step{step}-{}", std::process::id()));
            let _ = fs::remove_dir_all(&dest);
            fs::create_dir_all(&dest).unwrap();
            for (f, text) in [("a.png", "old a"), ("b.png", "old b"), ("mine.txt", "user")] {
                fs::write(dest.join(f), text).unwrap();
            }
            let journal = Journal {
                pid: dead,
                staging: format!("{STAGING_PREFIX}{dead}"),
                previous: format!("{PREVIOUS_PREFIX}{dead}"),
                old: strings(&["a.png", "b.png"]),
                outgoing: strings(&["a.png", "b.png"]),
                incoming: strings(&["a.png", "c.png"]),
                manifest: strings(&["a.png", "c.png"]),
            };
            let (staging, previous) = (dest.join(&journal.staging), dest.join(&journal.previous));
            fs::create_dir(&staging).unwrap();
            fs::create_dir(&previous).unwrap();
            fs::write(staging.join("a.png"), "new a").unwrap();
            fs::write(staging.join("c.png"), "new c").unwrap();
            write_bytes_atomic(&dest.join(JOURNAL), journal.to_json().as_bytes()).unwrap();
            assert_eq!(Journal::read(&dest).as_ref(), Some(&journal));
            if step >= 1 {
                fs::rename(dest.join("a.png"), previous.join("a.png")).unwrap();
                fs::rename(dest.join("b.png"), previous.join("b.png")).unwrap();
            }
            if step >= 2 {
                fs::rename(staging.join("a.png"), dest.join("a.png")).unwrap();
            }
            if step >= 3 {
                fs::rename(staging.join("c.png"), dest.join("c.png")).unwrap();
            }
            if step >= 4 {
                fs::remove_file(dest.join(JOURNAL)).unwrap();
                write_bytes_atomic(
                    &dest.join(MANIFEST),
                    manifest_json(&journal.manifest).as_bytes(),
                )
                .unwrap();
            }
            assert_eq!(finish_interrupted(&dest).unwrap(), step < 4, "step {step}");
            // The staging folder of the gone process is removed by the staging clean-up that
            // follows in `StagedDir::new`; here only the journal's own work is checked.
            let _ = fs::remove_dir_all(&staging);
            assert_eq!(names(&dest), [MANIFEST, "a.png", "c.png", "mine.txt"], "step {step}");
            assert_eq!(fs::read_to_string(dest.join("a.png")).unwrap(), "new a", "step {step}");
            assert_eq!(fs::read_to_string(dest.join("c.png")).unwrap(), "new c", "step {step}");
            assert_eq!(read_manifest(&dest), journal.manifest, "step {step}");
            fs::remove_dir_all(&dest).unwrap();
        }
    }

    /// A journal of a running process (this one's parent, alive) is left alone and the new run
    /// refused; a damaged or
    /// foreign journal, or one naming folders outside the destination, is never acted on.
    #[test]
    fn journals_of_live_processes_and_foreign_journals_are_left_alone() {
        let dest =
            std::env::temp_dir().join(format!("kfuse-in-place-foreign-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dest);
        fs::create_dir_all(&dest).unwrap();
        fs::write(dest.join("a.png"), "old a").unwrap();
        let live = std::os::unix::process::parent_id();
        let journal = Journal {
            pid: live,
            staging: format!("{STAGING_PREFIX}{live}"),
            previous: format!("{PREVIOUS_PREFIX}{live}"),
            old: strings(&["a.png"]),
            outgoing: strings(&["a.png"]),
            incoming: strings(&["c.png"]),
            manifest: strings(&["c.png"]),
        };
        write_bytes_atomic(&dest.join(JOURNAL), journal.to_json().as_bytes()).unwrap();
        let err = finish_interrupted(&dest).unwrap_err().to_string();
        assert!(err.contains(&format!("process {live}")), "{err}");
        assert_eq!(names(&dest), [JOURNAL, "a.png"]);
        let dead = 4_194_305 + std::process::id() % 1000;
        let escaping = journal.to_json().replace(&format!("{live}"), &dead.to_string()).replace(
            &format!("\"{STAGING_PREFIX}{dead}\""),
            &format!("\"../{STAGING_PREFIX}{dead}\""),
        );
        for text in [escaping, "{\"format\": \"kfuse-publishing\"".to_string(), "x".repeat(100)] {
            fs::write(dest.join(JOURNAL), &text).unwrap();
            assert_eq!(Journal::read(&dest), None, "{text}");
            assert!(!finish_interrupted(&dest).unwrap());
            assert_eq!(fs::read_to_string(dest.join("a.png")).unwrap(), "old a");
        }
        fs::remove_dir_all(&dest).unwrap();
    }
}
