use super::staged_dir::REPLACED_PREFIX;
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

pub(super) fn names(dir: &Path) -> Vec<String> {
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
    for keep in [".rig.json.partial-1", &format!(".g.json.partial-{dead}"), ".rig.json.partial-x"] {
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
