//! `remove_unpublished` (what a second Ctrl-C runs before exiting) deletes the temporaries of
//! every output not yet published and leaves the published ones whole. Its own test binary:
//! it deletes every temporary of the process, which would break other tests running beside it.

use std::fs;

use kfuse_io::atomic::{StagedDir, StagedFiles, remove_unpublished, write_bytes_atomic};

#[test]
fn a_hard_stop_leaves_only_published_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    write_bytes_atomic(&d.join("published.json"), b"whole").unwrap();
    let mut files = StagedFiles::new();
    files.add(&d.join("rig.json"), b"rig").unwrap();
    files.add(&d.join("rig.yaml"), b"yaml").unwrap();
    let staged = StagedDir::new(&d.join("report")).unwrap();
    fs::write(staged.join("figure.png"), b"png").unwrap();
    let names = || {
        let mut n: Vec<String> = fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        n.sort();
        n
    };
    // Two temporaries and a staging folder beside the published file.
    assert_eq!(names().len(), 4, "{:?}", names());
    let stopped = remove_unpublished();
    assert_eq!(stopped.removed(), 3);
    assert_eq!(names(), ["published.json"]);
    assert_eq!(fs::read(d.join("published.json")).unwrap(), b"whole");
    drop(stopped);
    // Dropping the stagers afterwards finds nothing left to delete, and writing works again.
    drop(files);
    drop(staged);
    write_bytes_atomic(&d.join("after.json"), b"x").unwrap();
    assert_eq!(names(), ["after.json", "published.json"]);
}
