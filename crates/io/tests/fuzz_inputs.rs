//! Fuzz-style tests of the readers of untrusted files: the `.mat` reader, rig JSON and image
//! headers. A committed corpus of crafted files (`tests/corpus/`) is replayed, then a bounded
//! run of seeded random mutations of valid files: every input must give `Ok` or an error
//! naming the file, never a panic, and never a value larger than the limits allow.

use std::io::Write;
use std::path::{Path, PathBuf};

use geometry::{CameraModel, Distortion, Image, Intrinsics, Rig, RigidTransform};
use kfuse_io::mat::{MatFile, MatValue, NumericArray, NumericData, encode};
use kfuse_io::{images, rig as rigio};
use nalgebra::Vector3;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Mutations per seed file in the random runs: bounded so the test takes seconds.
const MUTATIONS: usize = 400;

fn corpus(kind: &str) -> Vec<PathBuf> {
    let dir = manifest_dir().join("tests/corpus").join(kind);
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kfuse-fuzz-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One error line that names the file, without control characters echoed from the input.
fn assert_clean_error(err: &str, file: &str) {
    assert!(err.contains(file), "error does not name {file}: {err}");
    assert!(!err.contains('\n'), "multi-line error: {err}");
    assert!(!err.chars().any(|c| c.is_control()), "control characters echoed: {err:?}");
}

/// Flips, overwrites, truncates or duplicates a few bytes.
fn mutate(rng: &mut ChaCha8Rng, bytes: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        if b.is_empty() {
            break;
        }
        let i = rng.random_range(0..b.len());
        match rng.random_range(0..5) {
            0 => b[i] ^= 1 << rng.random_range(0..8),
            1 => b[i] = [0x00, 0xff, 0x7f, 0x80][rng.random_range(0..4)],
            2 => b.truncate(i),
            3 => {
                let j = rng.random_range(i..b.len());
                let chunk = b[i..j.min(i + 16)].to_vec();
                b.splice(i..i, chunk);
            }
            _ => {
                // A 32-bit field set to an extreme value (sizes, counts, dimensions).
                let v: u32 =
                    [u32::MAX, 0x7fff_ffff, 0x8000_0000, 0, 0xffff][rng.random_range(0..5)];
                for (k, byte) in v.to_le_bytes().into_iter().enumerate() {
                    if let Some(x) = b.get_mut(i + k) {
                        *x = byte;
                    }
                }
            }
        }
    }
    b
}

fn compressed(uncompressed_file: &[u8]) -> Vec<u8> {
    // Re-pack every element after the header as one miCOMPRESSED element.
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&uncompressed_file[128..]).unwrap();
    let data = z.finish().unwrap();
    let mut out = uncompressed_file[..128].to_vec();
    out.extend_from_slice(&15u32.to_le_bytes());
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(&data);
    out
}

fn seed_mat_files() -> Vec<Vec<u8>> {
    let vars = vec![
        ("M", MatValue::double_matrix(2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
        (
            "s",
            MatValue::structure(vec![
                ("fx", MatValue::scalar(365.0)),
                ("name", MatValue::string("ir")),
                ("inner", MatValue::structure(vec![("x", MatValue::scalar(-2.5))])),
            ]),
        ),
        (
            "img",
            MatValue::Numeric(NumericArray {
                dims: vec![4, 3, 3],
                real: NumericData::UInt8((0..36).collect()),
                imag: None,
            }),
        ),
        (
            "c",
            MatValue::Cell {
                dims: vec![1, 2],
                cells: vec![MatValue::scalar(1.0), MatValue::string("two")],
            },
        ),
    ];
    let plain = encode(&vars).unwrap();
    let packed = compressed(&plain);
    assert!(MatFile::parse(&packed, Path::new("seed.mat")).is_ok());
    vec![plain, packed]
}

#[test]
fn mat_corpus_is_refused_with_one_clean_line() {
    let files = corpus("mat");
    // tests/corpus/mat holds 15 crafted files (counted 2026-12-01); ≥ 10 only guards against a
    // missing or moved corpus folder.
    assert!(files.len() >= 10, "corpus missing: {files:?}");
    for path in files.iter().filter(|p| p.extension().is_some_and(|e| e == "mat")) {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let err = match MatFile::read(path) {
            Ok(f) => {
                panic!("{name}: crafted file accepted with {:?}", f.names().collect::<Vec<_>>())
            }
            Err(e) => e.to_string(),
        };
        assert_clean_error(&err, &name);
    }
}

#[test]
fn mat_limits_name_what_was_declared() {
    let err = MatFile::read(&corpus_file("mat", "cell_2147483647x2147483647.mat")).unwrap_err();
    assert!(err.to_string().contains("2147483647×2147483647"), "{err}");
    let err = MatFile::read(&corpus_file("mat", "compressed_huge_cell.mat")).unwrap_err();
    assert!(err.to_string().contains("only"), "{err}");
    let err = MatFile::read(&corpus_file("mat", "uint8_stored_double_1e9.mat")).unwrap_err();
    assert!(err.to_string().contains("limit"), "{err}");
    // A zlib bomb: 1 GB of zeros in about 1 MB stops at the cap.
    let dir = scratch("bomb");
    let mut body = seed_mat_files()[0][..128].to_vec();
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..1024 {
        z.write_all(&zeros).unwrap();
    }
    let data = z.finish().unwrap();
    body.extend_from_slice(&15u32.to_le_bytes());
    body.extend_from_slice(&(data.len() as u32).to_le_bytes());
    body.extend_from_slice(&data);
    std::fs::write(dir.join("bomb.mat"), &body).unwrap();
    let err = MatFile::read(&dir.join("bomb.mat")).unwrap_err().to_string();
    assert!(err.contains("bomb.mat") && err.contains("zlib bomb"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn corpus_file(kind: &str, name: &str) -> PathBuf {
    manifest_dir().join("tests/corpus").join(kind).join(name)
}

#[test]
fn mat_random_mutations_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let (mut ok, mut refused) = (0, 0);
    for seed in seed_mat_files() {
        for _ in 0..MUTATIONS {
            let bytes = mutate(&mut rng, &seed);
            match MatFile::parse(&bytes, Path::new("mutant.mat")) {
                Ok(f) => {
                    ok += 1;
                    for n in f.names() {
                        let v = f.get(n).unwrap();
                        // Loose ceiling: the reader caps one array at MAX_ARRAY_BYTES and a
                        // file's arrays together at MAX_TOTAL_ARRAY_BYTES (3 ×); 4× fails only
                        // a reader that skipped the caps.
                        assert!(v.memory_bytes() <= kfuse_io::mat::MAX_ARRAY_BYTES * 4);
                    }
                }
                Err(e) => {
                    refused += 1;
                    assert_clean_error(&e.to_string(), "mutant.mat");
                }
            }
        }
    }
    // Both outcomes occur, so the mutations reach past the header checks.
    // Guard, not a measurement: of 2 seeds × MUTATIONS (800) mutants each outcome must occur
    // more than 20 times (2.5 %), i.e. neither all refused at the header nor all harmless.
    assert!(ok > 20 && refused > 20, "ok {ok}, refused {refused}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]
    #[test]
    fn mat_any_bytes_after_a_valid_header_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut bytes = seed_mat_files()[0][..128].to_vec();
        bytes.extend_from_slice(&tail);
        if let Err(e) = MatFile::parse(&bytes, Path::new("any.mat")) {
            assert_clean_error(&e.to_string(), "any.mat");
        }
    }
}

fn kinect_rig() -> Rig {
    let depth = CameraModel::new(
        512,
        424,
        Intrinsics::new(365.0, 365.0, 255.5, 211.5),
        Distortion { k1: 0.09, k2: -0.27, p1: 0.0, p2: 0.0, k3: 0.1 },
    );
    let color = CameraModel::new(
        1920,
        1080,
        Intrinsics::new(1060.0, 1060.0, 959.5, 539.5),
        Distortion::NONE,
    );
    Rig::new(
        depth,
        color,
        RigidTransform::from_axis_angle(
            Vector3::new(0.0, 0.01, 0.0),
            Vector3::new(-0.052, 0.0, 0.0),
        ),
    )
}

#[test]
fn rig_json_mutations_never_panic_and_accepted_rigs_are_plausible() {
    let dir = scratch("rig");
    let text = kinect_rig().to_json();
    let path = dir.join("rig.json");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let numbers =
        ["1e308", "-1e308", "0", "-0.0", "1e-300", "52", "30000", "NaN", "99999999999999999999"];
    let (mut ok, mut refused) = (0, 0);
    for i in 0..MUTATIONS * 2 {
        let mutant = if i % 2 == 0 {
            mutate(&mut rng, text.as_bytes())
        } else {
            // Replace one number of the file with an extreme one.
            let spots: Vec<usize> = text
                .char_indices()
                .filter(|&(k, c)| {
                    c.is_ascii_digit()
                        && !text[..k]
                            .ends_with(|p: char| p.is_ascii_digit() || p == '.' || p == '-')
                })
                .map(|(k, _)| k)
                .collect();
            let at = spots[rng.random_range(0..spots.len())];
            let end = text[at..]
                .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == 'e' || c == '-'))
                .unwrap()
                + at;
            let mut t = text.clone();
            t.replace_range(at..end, numbers[rng.random_range(0..numbers.len())]);
            t.into_bytes()
        };
        std::fs::write(&path, &mutant).unwrap();
        match rigio::read_pair(&path) {
            Ok(rig) => {
                ok += 1;
                assert!(rig.plausibility_problems().is_empty());
                assert!(rig.color_from_depth.translation.norm() <= geometry::rig::MAX_BASELINE_M);
            }
            Err(e) => {
                refused += 1;
                assert_clean_error(&e.to_string(), "rig.json");
            }
        }
    }
    // Guard, not a measurement: of 2 × MUTATIONS (800) mutants each outcome must occur more
    // than 10 times, i.e. the mutations reach both the parser's errors and accepted rigs.
    assert!(ok > 10 && refused > 10, "ok {ok}, refused {refused}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn image_corpus_and_mutations_never_panic_or_decode_past_the_limits() {
    let dir = scratch("img");
    // Crafted headers in the corpus: huge declared sizes, refused from the header.
    for path in corpus("image") {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let err = images::read_color(&path).unwrap_err().to_string();
        assert_clean_error(&err, &name);
        let err = images::read_depth(&path, 1e-3).unwrap_err().to_string();
        assert_clean_error(&err, &name);
    }
    // Mutations of small valid files of every format.
    let color = Image::from_fn(24, 16, |x, y| [x as u8 * 10, y as u8 * 15, 7]);
    let depth = Image::from_fn(24, 16, |x, y| 0.5 + 0.01 * (x + y) as f32);
    images::write_color_png(&dir.join("c.png"), &color).unwrap();
    images::write_depth_png16(&dir.join("d.png"), &depth).unwrap();
    images::write_depth_tiff(&dir.join("d.tif"), &depth).unwrap();
    images::write_depth_exr(&dir.join("d.exr"), &depth).unwrap();
    image::RgbImage::from_fn(24, 16, |x, y| image::Rgb([x as u8, y as u8, 3]))
        .save(dir.join("c.jpg"))
        .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mutant = dir.join("mutant");
    for seed in ["c.png", "d.png", "d.tif", "d.exr", "c.jpg"] {
        let bytes = std::fs::read(dir.join(seed)).unwrap();
        for _ in 0..MUTATIONS / 2 {
            std::fs::write(&mutant, mutate(&mut rng, &bytes)).unwrap();
            for result in [
                images::read_color(&mutant).map(|i| i.size()),
                images::read_depth(&mutant, 1e-3).map(|i| i.size()),
                kfuse_io::image_header::image_size(&mutant),
            ] {
                match result {
                    Ok((w, h)) => assert!(
                        // kfuse_io::image_header::MAX_IMAGE_SIDE (16 384 px) and
                        // MAX_IMAGE_PIXELS (50 000 000).
                        w <= 16_384 && h <= 16_384 && w * h <= 50_000_000,
                        "{seed}: {w}x{h} decoded"
                    ),
                    Err(e) => assert_clean_error(&e.to_string(), "mutant"),
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
