//! Tests of the `.mat` reader and writer.

use super::*;
use std::path::Path;

#[test]
fn column_major_to_row_major_3d() {
    // MATLAB A(i,j,k) with dims 2×3×2, column-major value = i + 10 j + 100 k.
    let dims = [2, 3, 2];
    let mut col = Vec::new();
    for k in 0..2 {
        for j in 0..3 {
            for i in 0..2 {
                col.push(i + 10 * j + 100 * k);
            }
        }
    }
    let row = column_to_row_major(&col, &dims);
    for i in 0..2 {
        for j in 0..3 {
            for k in 0..2 {
                assert_eq!(row[(i * 3 + j) * 2 + k], i + 10 * j + 100 * k);
            }
        }
    }
    assert_eq!(row_to_column_major(&row, &dims), col);
}

#[test]
fn writer_round_trip_all_kinds() {
    let vars = vec![
        ("M", MatValue::double_matrix(2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
        (
            "s",
            MatValue::structure(vec![
                ("name", MatValue::string("ir_")),
                ("inner", MatValue::structure(vec![("x", MatValue::scalar(-2.5))])),
            ]),
        ),
        (
            "i16",
            MatValue::Numeric(NumericArray {
                dims: vec![1, 3],
                real: NumericData::Int16(vec![-7, 0, 300]),
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
    let bytes = encode(&vars).unwrap();
    let f = MatFile::parse(&bytes, Path::new("mem.mat")).unwrap();
    let m = f.matrix("M").unwrap();
    assert_eq!((m.rows, m.cols), (2, 3));
    assert_eq!(m.at(1, 0), 4.0);
    assert_eq!(f.string("s.name").unwrap(), "ir_");
    assert_eq!(f.scalar("s.inner.x").unwrap(), -2.5);
    assert_eq!(f.numeric("i16").unwrap().real, NumericData::Int16(vec![-7, 0, 300]));
    assert_eq!(f.require("c").unwrap().as_cells().unwrap()[1].as_string().unwrap(), "two");
    let err = f.scalar("s.missing").unwrap_err().to_string();
    assert!(
        err.contains("mem.mat")
            && err.contains("no field 'missing'")
            && err.contains("name, inner"),
        "{err}"
    );
    let err = f.matrix("nope").unwrap_err().to_string();
    assert!(err.contains("no variable 'nope'") && err.contains("M, s, i16, c"), "{err}");
}

#[test]
fn complex_and_logical_arrays() {
    let vars = vec![
        (
            "z",
            MatValue::Numeric(NumericArray {
                dims: vec![1, 2],
                real: NumericData::Double(vec![1.0, 2.0]),
                imag: Some(NumericData::Double(vec![0.5, -0.5])),
            }),
        ),
        (
            "mask",
            MatValue::Numeric(NumericArray {
                dims: vec![2, 1],
                real: NumericData::Logical(vec![1, 0]),
                imag: None,
            }),
        ),
    ];
    let f = MatFile::parse(&encode(&vars).unwrap(), Path::new("c.mat")).unwrap();
    let z = f.numeric("z").unwrap();
    assert_eq!(z.imag, Some(NumericData::Double(vec![0.5, -0.5])));
    let err = f.matrix("z").unwrap_err().to_string();
    assert!(err.contains("c.mat") && err.contains("complex"), "{err}");
    assert_eq!(f.numeric("mask").unwrap().class(), MatClass::Logical);
    assert_eq!(f.matrix("mask").unwrap().data, vec![1.0, 0.0]);
}

#[test]
fn truncated_and_garbage_files_give_errors_naming_the_file() {
    let bytes = encode(&[("M", MatValue::double_matrix(4, 4, &[1.0; 16]))]).unwrap();
    for cut in [10, 128 + 4, 128 + 40, bytes.len() - 9] {
        let err = MatFile::parse(&bytes[..cut], Path::new("cut.mat")).unwrap_err().to_string();
        assert!(err.starts_with("cut.mat:"), "{err}");
    }
    let err = MatFile::parse(&[b'x'; 300], Path::new("junk.mat")).unwrap_err().to_string();
    assert!(err.contains("junk.mat") && err.contains("not a MATLAB v5"), "{err}");
}

/// Images and random bytes given as a `.mat` file: the error says what the file is and never
/// echoes its bytes (printable ASCII only, one line).
#[test]
fn non_mat_files_are_named_without_their_bytes() {
    let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR".to_vec();
    png.resize(300, 0xfe);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let random: Vec<u8> = (0..300)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 24) as u8 | 0x80
        })
        .collect();
    let mut text = b"# some notes\nline two".to_vec();
    text.resize(300, b' ');
    for (bytes, says) in [
        (&png, "is a PNG image, not a MATLAB .mat file"),
        (&random, "binary data of another kind"),
        (&text, "it starts with '# some notes line two'"),
    ] {
        let err = MatFile::parse(bytes, Path::new("x.mat")).unwrap_err().to_string();
        assert!(err.starts_with("x.mat:") && err.contains(says), "{err}");
        assert!(err.chars().all(|c| c.is_ascii_graphic() || c == ' '), "not plain text: {err:?}");
    }
}

use geometry::testdata::shared_data_or_skip as shared_data;

#[test]
fn bouguet_left_calibration_matches_its_readme() {
    let Some(data) = shared_data("bouguet_left_calibration_matches_its_readme") else { return };
    let f = MatFile::read(&data.join("kinect-lab/Calib_Results_left.mat")).unwrap();
    assert!(f.header().starts_with("MATLAB 5.0 MAT-file"));
    // README: "Bouguet's IR result (fx 364.126, fy 365.126)"; stated to 3 decimals.
    let fc = f.matrix_of_size("fc", 2, 1).unwrap();
    assert!((fc.data[0] - 364.126).abs() < 5e-4 && (fc.data[1] - 365.126).abs() < 5e-4, "{fc:?}");
    // Principal point fixed at ((w-1)/2, (h-1)/2) = (255.5, 211.5): exact in the file.
    let cc = f.matrix("cc").unwrap();
    assert_eq!(cc.data, vec![255.5, 211.5]);
    let kk = f.matrix_of_size("KK", 3, 3).unwrap();
    assert_eq!(
        (kk.at(0, 0), kk.at(0, 2), kk.at(1, 1), kk.at(2, 2)),
        (fc.data[0], 255.5, fc.data[1], 1.0)
    );
    // k3 fixed at 0 (README); stored as an integer-valued double.
    let kc = f.matrix_of_size("kc", 5, 1).unwrap();
    assert_eq!(kc.data[4], 0.0);
    // The Kinect v2 depth image size (DESIGN.md), which the toolbox stores as nx, ny.
    assert_eq!(f.scalar("nx").unwrap(), 512.0);
    assert_eq!(f.scalar("ny").unwrap(), 424.0);
    assert_eq!(f.string("calib_name").unwrap(), "ir_");
    // Corners: 2×35, and README says 0-based pixels inside the 512×424 image.
    let x1 = f.matrix_of_size("x_1", 2, 35).unwrap();
    assert!(x1.data.iter().all(|v| (0.0..512.0).contains(v)));
    // Board points: 7×5 inner corners, 40 mm squares, x = 0..160 mm (README).
    let big_x = f.matrix_of_size("X_1", 3, 35).unwrap();
    assert_eq!(&big_x.data[..5], &[0.0, 40.0, 80.0, 120.0, 160.0]);
    // Counted with an independent Python zlib/struct walk of the file (2026-12-01): 224 variables
    // (H_1, H_10, …); > 200 fails when a compressed element stops the reader early.
    assert!(f.names().count() > 200);
}

#[test]
fn bouguet_stereo_and_kinect_data_read() {
    let Some(data) = shared_data("bouguet_stereo_and_kinect_data_read") else { return };
    let st = MatFile::read(&data.join("kinect-lab/Calib_Results_stereo.mat")).unwrap();
    // README: "stereo (T = (-52.195, -0.262, 0.625) mm)", stated to 3 decimals.
    let t = st.matrix_of_size("T", 3, 1).unwrap();
    for (got, want) in t.data.iter().zip([-52.195, -0.262, 0.625]) {
        assert!((got - want).abs() < 5e-4, "T = {:?}", t.data);
    }
    let r = st.matrix_of_size("R", 3, 3).unwrap();
    // R must be a rotation: rows orthonormal to rounding (1e-9 ≫ double round-off).
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| r.at(i, k) * r.at(j, k)).sum();
            assert!((dot - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9);
        }
    }
    let kd = MatFile::read(&data.join("kinect-lab/KinectData.mat")).unwrap();
    let img = kd.numeric("Image").unwrap();
    // The Kinect v2 colour frame (1080 rows × 1920 columns × RGB, DESIGN.md), uint8.
    assert_eq!(img.dims, vec![1080, 1920, 3]);
    assert_eq!(img.class(), MatClass::UInt8);
    // The lab's stereo intrinsics are copied into Cparam/Dparam: same numbers as KK_*.
    let kk_right = st.matrix("KK_right").unwrap();
    assert_eq!(kd.scalar("Cparam.fx").unwrap(), kk_right.at(0, 0));
    assert_eq!(kd.scalar("Dparam.cx").unwrap(), 255.5);
    assert_eq!(kd.matrix("T").unwrap().data, t.data);
}

#[test]
fn course_synthdata_reads_structs_and_single_arrays() {
    let Some(data) = shared_data("course_synthdata_reads_structs_and_single_arrays") else {
        return;
    };
    let f = MatFile::read(&data.join("course/synthdata.mat")).unwrap();
    let depth = f.numeric("Depth").unwrap();
    // data README: synthdata.mat holds Image 480×640×3 and Depth 480×640 float32.
    assert_eq!((depth.dims.clone(), depth.class()), (vec![480, 640], MatClass::Single));
    let image = f.numeric("Image").unwrap();
    assert_eq!(image.dims, vec![480, 640, 3]);
    // fp = f / pixelsize (data README): 0.024 / 5.625e-5 = 426.67 px.
    let fp = f.scalar("Dparam.fp").unwrap();
    let ratio = f.scalar("Dparam.f").unwrap() / f.scalar("Dparam.pixelsize").unwrap();
    assert!((fp - ratio).abs() < 1e-9 * fp, "fp {fp} vs f/pixelsize {ratio}");
    // The value stored in synthdata.mat (a 1-based MATLAB index, see kfuse_io::course's
    // docs: 0-based 319); this reader returns it as stored.
    assert_eq!(f.scalar("Cparam.cx").unwrap(), 320.0);
    let err = f.scalar("Dparam.k1").unwrap_err().to_string();
    assert!(err.contains("synthdata.mat") && err.contains("no field 'k1'"), "{err}");
    // A 3-D array is not a matrix: the error says so.
    let err = f.matrix("Image").unwrap_err().to_string();
    assert!(err.contains("3 dimensions"), "{err}");
}

#[test]
fn corrupt_compressed_data_is_reported() {
    let Some(data) = shared_data("corrupt_compressed_data_is_reported") else { return };
    let bytes = std::fs::read(data.join("kinect-lab/Calib_Results_stereo.mat")).unwrap();
    // Cut in the middle of the first compressed element.
    let err = MatFile::parse(&bytes[..200], Path::new("cut.mat")).unwrap_err().to_string();
    assert!(err.starts_with("cut.mat:") && err.contains("truncated"), "{err}");
    // Scramble the deflate stream of the first element (zlib's checksum catches it).
    let mut bad = bytes.clone();
    for b in &mut bad[150..190] {
        *b ^= 0x5a;
    }
    let err = MatFile::parse(&bad, Path::new("bad.mat")).unwrap_err().to_string();
    assert!(err.starts_with("bad.mat:") && err.contains("variable #1"), "{err}");
}
