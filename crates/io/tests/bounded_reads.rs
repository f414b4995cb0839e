//! Devices and pipes given as a rig, depth, colour, `.mat` or PLY file are read to at most the
//! format's byte limit (issue 51: the size limits looked at the stated length, 0 for devices
//! and pipes, and read `/dev/zero` to 4 GB). Each case ends in an error naming the file; a
//! FIFO's writer counts what the reader took, which bounds the memory used.

use std::io::Write;
use std::path::{Path, PathBuf};

use kfuse_io::images::{read_color, read_depth};
use kfuse_io::rig::{MAX_RIG_FILE_BYTES, read_rig};

/// What the kernel's pipe buffer can hold beyond what the reader took: 1 MiB is Linux's
/// largest pipe size (`/proc/sys/fs/pipe-max-size`), the default being 64 KiB.
const PIPE_SLACK: u64 = 1 << 20;
/// Bytes per write of the FIFO's writer.
const CHUNK: usize = 64 << 10;

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("kfuse-bounded-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A FIFO at `path` whose writer sends `head`, then `fill` bytes until the reader closes it;
/// the returned thread's result is the number of bytes the writer got into the pipe.
fn endless_fifo(path: &Path, head: &'static [u8], fill: u8) -> std::thread::JoinHandle<u64> {
    let st = std::process::Command::new("mkfifo").arg(path).status().expect("mkfifo runs");
    assert!(st.success(), "mkfifo {}", path.display());
    let path = path.to_path_buf();
    std::thread::spawn(move || {
        // Opening blocks until the reader opens its end.
        let mut f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        let mut sent = 0u64;
        if f.write_all(head).is_err() {
            return sent;
        }
        sent += head.len() as u64;
        let chunk = vec![fill; CHUNK];
        // A broken pipe (the reader gave up) ends the loop; SIGPIPE is ignored by Rust's runtime.
        while f.write_all(&chunk).is_ok() {
            sent += CHUNK as u64;
        }
        sent
    })
}

#[test]
fn rig_from_dev_zero_stops_at_the_limit() {
    let e = read_rig(Path::new("/dev/zero")).unwrap_err().to_string();
    assert!(e.starts_with("/dev/zero: "), "{e}");
    assert!(e.contains(&format!("more than {MAX_RIG_FILE_BYTES} bytes")), "{e}");
    assert!(e.contains("a rig file") && e.contains("kfuse calibrate"), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
}

#[test]
fn rig_from_a_fifo_stops_at_the_limit() {
    let dir = temp_dir("rig");
    let fifo = dir.join("rig.json");
    let writer = endless_fifo(&fifo, b"{\"format\": ", b' ');
    let e = read_rig(&fifo).unwrap_err().to_string();
    let sent = writer.join().unwrap();
    assert!(e.contains(&format!("more than {MAX_RIG_FILE_BYTES} bytes")), "{e}");
    assert!(e.starts_with(&fifo.display().to_string()), "{e}");
    // The reader took limit + 1 bytes; the pipe held at most PIPE_SLACK more, the writer's
    // last chunk was refused.
    assert!(sent > MAX_RIG_FILE_BYTES, "{sent}");
    assert!(sent <= MAX_RIG_FILE_BYTES + 1 + PIPE_SLACK + CHUNK as u64, "{sent}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn depth_and_colour_from_devices_fail_after_the_signature() {
    for dev in ["/dev/zero", "/dev/urandom"] {
        let e = read_depth(Path::new(dev), 0.001).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{dev}: ")) && e.contains("unknown format"), "{e}");
        assert!(e.contains("depth must be"), "{e}");
        let e = read_color(Path::new(dev)).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{dev}: ")) && e.contains("unknown format"), "{e}");
    }
}

#[test]
fn depth_from_a_fifo_of_zeros_fails_after_the_signature() {
    let dir = temp_dir("depth");
    let fifo = dir.join("depth.png");
    let writer = endless_fifo(&fifo, b"", 0);
    let e = read_depth(&fifo, 0.001).unwrap_err().to_string();
    let sent = writer.join().unwrap();
    assert!(e.contains("unknown format") && e.contains("depth must be"), "{e}");
    // 8 bytes were read; what was sent is what the pipe held (one chunk or two).
    assert!(sent <= PIPE_SLACK + CHUNK as u64, "{sent}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn mat_and_ply_from_dev_zero_fail_after_the_header() {
    let e = kfuse_io::mat::MatFile::read(Path::new("/dev/zero")).unwrap_err().to_string();
    assert!(e.starts_with("/dev/zero: "), "{e}");
    assert!(e.contains("'MATLAB 5.0 MAT-file' header"), "{e}");
    let e = kfuse_io::ply::read_cloud_ply(Path::new("/dev/zero"), None).unwrap_err().to_string();
    assert!(e.starts_with("/dev/zero: ") && e.contains("not a PLY file"), "{e}");
}
