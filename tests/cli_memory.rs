//! Peak memory of `kfuse fuse` (issue 12): a Kinect v2-size frame, crafted `.mat` files and a
//! zlib bomb, each run as a child process whose peak resident set size is read with
//! `getrusage(RUSAGE_CHILDREN)` (the largest of the children waited for so far, so every
//! child is checked against the same bound in the order they run). Not a wall clock.
//!
//! This file is its own test binary with one test so that no other child process of the
//! same binary enters the figure.

use std::path::Path;
use std::process::Command;

use geometry::synth;
use kfuse_io::{images, rig as rigio};
use nix::sys::resource::{UsageWho, getrusage};

/// The bound of issue 12 for `fuse` on a Kinect frame, MiB.
const FUSE_PEAK_LIMIT_MIB: i64 = 250;

/// Largest peak RSS of the children waited for so far, MiB (Linux reports KiB).
fn children_peak_mib() -> i64 {
    getrusage(UsageWho::RUSAGE_CHILDREN).expect("getrusage").max_rss() / 1024
}

fn run(args: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_kfuse")).args(args).output().expect("run kfuse");
    (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
}

/// A `.mat` file whose one compressed variable declares a `uint8` array of `n` zero bytes:
/// a zlib bomb of about n/1000 bytes.
fn zlib_bomb(path: &Path, n: u32) {
    use std::io::Write;
    let el = |ty: u32, data: &[u8]| {
        let mut b = ty.to_le_bytes().to_vec();
        b.extend_from_slice(&(data.len() as u32).to_le_bytes());
        b.extend_from_slice(data);
        while !b.len().is_multiple_of(8) {
            b.push(0);
        }
        b
    };
    let mut body = el(6, &[9, 0, 0, 0, 0, 0, 0, 0]); // flags: uint8
    body.extend(el(5, &[1i32.to_le_bytes(), (n as i32).to_le_bytes()].concat()));
    body.extend(el(1, b"z"));
    body.extend_from_slice(&2u32.to_le_bytes()); // miUINT8
    body.extend_from_slice(&n.to_le_bytes());
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    z.write_all(&14u32.to_le_bytes()).unwrap();
    z.write_all(&(body.len() as u32 + n).to_le_bytes()).unwrap();
    z.write_all(&body).unwrap();
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..n / (1 << 20) {
        z.write_all(&zeros).unwrap();
    }
    let compressed = z.finish().unwrap();
    let mut file = b"MATLAB 5.0 MAT-file, zlib bomb".to_vec();
    file.resize(116, b' ');
    file.extend_from_slice(&[0; 8]);
    file.extend_from_slice(&0x0100u16.to_le_bytes());
    file.extend_from_slice(b"IM");
    file.extend_from_slice(&15u32.to_le_bytes());
    file.extend_from_slice(&(compressed.len() as u32).to_le_bytes());
    file.extend_from_slice(&compressed);
    std::fs::write(path, file).unwrap();
}

#[test]
fn fuse_peak_memory_stays_bounded() {
    let dir = std::env::temp_dir().join(format!("kfuse-mem-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    assert_eq!(children_peak_mib(), 0, "another child ran in this test binary");

    // A Kinect v2-size frame (512x424 depth, 1920x1080 colour), rendered in this process.
    let setup = synth::kinect_preset(true);
    let frame = synth::render(&setup);
    images::write_color_png(&dir.join("color.png"), &frame.color).unwrap();
    images::write_depth_png16(&dir.join("depth.png"), &frame.depth).unwrap();
    rigio::write_rig(&dir.join("rig.json"), &setup.rig).unwrap();
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let (ok, err) = run(&[
        "fuse",
        "--rig",
        &d("rig.json"),
        "--color",
        &d("color.png"),
        "--depth",
        &d("depth.png"),
        "--out",
        &d("out"),
    ]);
    assert!(ok, "{err}");
    let peak = children_peak_mib();
    eprintln!("fuse on a Kinect frame: peak RSS {peak} MiB");
    // Issue 12's spec ("fuse on a Kinect frame stays under 250 MB peak"); measured 175 MiB
    // in b44212b (2026-12-01, its commit message), so 75 MiB of margin.
    assert!(peak < FUSE_PEAK_LIMIT_MIB, "fuse peaked at {peak} MiB");

    // Crafted headers and a 2 GB zlib bomb: refused, memory within the same bound.
    let corpus = manifest_dir().join("crates/io/tests/corpus/mat");
    let mut inputs: Vec<_> =
        std::fs::read_dir(&corpus).unwrap().map(|e| e.unwrap().path()).collect();
    inputs.sort();
    zlib_bomb(&dir.join("bomb.mat"), 2_000_000_000);
    inputs.push(dir.join("bomb.mat"));
    for mat in inputs.iter().filter(|p| p.extension().is_some_and(|e| e == "mat")) {
        let (ok, err) = run(&["fuse", "--mat", mat.to_str().unwrap(), "--out", &d("mat-out")]);
        let name = mat.file_name().unwrap().to_string_lossy();
        assert!(!ok && err.contains(&*name) && !err.contains("panicked"), "{name}: {err}");
        let peak = children_peak_mib();
        // The same spec bound: every crafted file must be refused before it allocates more than a
        // Kinect frame's fusion does (b44212b: the 2.1 GB-RSS case now peaks under 175 MiB).
        assert!(peak < FUSE_PEAK_LIMIT_MIB, "{name}: peak {peak} MiB");
    }
    eprintln!("after {} crafted .mat files: peak RSS {} MiB", inputs.len(), children_peak_mib());
    let _ = std::fs::remove_dir_all(&dir);
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
