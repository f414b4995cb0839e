//! Stage tests of the fusion pipeline against `synth` ground truth: H1 on the course
//! preset, H5 on the Kinect preset's true depth, distorted vs undistorted input, bad input.

use geometry::fusion::{self, FusionOptions};
use geometry::synth;
use geometry::{DepthKind, GeometryError, Image};
use nalgebra::{Matrix3, Vector3};

/// Least-squares plane (unit normal, offset) and RMS distance of `points`.
fn plane_fit(points: &[Vector3<f64>]) -> (Vector3<f64>, f64, f64) {
    let c = points.iter().sum::<Vector3<f64>>() / points.len() as f64;
    let mut cov = Matrix3::zeros();
    for p in points {
        cov += (p - c) * (p - c).transpose();
    }
    let eig = cov.symmetric_eigen();
    let i = (0..3).min_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b])).unwrap();
    let n: Vector3<f64> = eig.eigenvectors.column(i).into();
    let (n, d) = if n.dot(&c) < 0.0 { (-n, -n.dot(&c)) } else { (n, n.dot(&c)) };
    let rms =
        (points.iter().map(|p| (n.dot(p) - d).powi(2)).sum::<f64>() / points.len() as f64).sqrt();
    (n, d, rms)
}

#[test]
fn course_h1_background_is_a_flat_plane_from_range_input() {
    let setup = synth::course_preset();
    let frame = synth::render(&setup);
    assert_eq!(frame.depth_kind, DepthKind::Range);
    let background = |kind: DepthKind| {
        let rays = fusion::depth_ray_table(&setup.rig.depth, kind);
        let (cloud, pixels) = fusion::backproject_cloud(&frame.depth, &rays);
        cloud
            .points
            .iter()
            .zip(&pixels)
            .filter(|(_, i)| frame.true_depth_object.data()[**i as usize] == 0)
            .map(|(p, _)| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect::<Vec<_>>()
    };
    let points = background(DepthKind::Range);
    // Guard: the course preset's plane is most of its 640 × 480 = 307 200 pixels (objects ~6 %).
    assert!(points.len() > 100_000, "{} background points", points.len());
    let (n, d, rms) = plane_fit(&points);
    // The preset's plane: through (0, 0, 19) with normal (0.05, -0.03, -1) (sign-normalised).
    let truth = Vector3::new(0.05, -0.03, -1.0).normalize();
    let truth = if truth.dot(&Vector3::new(0.0, 0.0, 19.0)) < 0.0 { -truth } else { truth };
    let truth_d = truth.dot(&Vector3::new(0.0, 0.0, 19.0));
    eprintln!("course background: RMS {rms:.2e} m, normal {n:?}, d {d}");
    // Noise-free f32 depth at ~19 m: rounding is ~1e-6 m (ulp(19) = 1.9e-6), so the RMS must
    // be at that level; 1e-5 m leaves 5x margin.
    // Measured 8.3e-7 m (issue 5's report); bar: issue 2 ("RMS at the data's noise level").
    assert!(rms < 1e-5, "background plane RMS {rms} m");
    // Not bent and in the right place: normal within 1e-5 rad, offset within 1e-4 m.
    assert!((n - truth).norm() < 1e-5, "normal {n} vs {truth}");
    assert!((d - truth_d).abs() < 1e-4, "offset {d} vs {truth_d}");
    // Reading the same range image as z bends the plane by metres: the test can fail.
    let (_, _, rms_wrong) = plane_fit(&background(DepthKind::Z));
    assert!(rms_wrong > 0.1, "range read as z should bend the plane, RMS {rms_wrong}");
}

#[test]
fn course_fusion_lands_on_the_objects() {
    let setup = synth::course_preset();
    let frame = synth::render(&setup);
    let out = fusion::run(
        &setup.rig,
        &frame.depth,
        frame.depth_kind,
        &frame.color,
        &FusionOptions::default(),
    )
    .unwrap();
    // Every z-buffered pixel holds the depth of the surface the colour camera sees there,
    // except at depth edges where the rounding to a pixel can put a sample across the edge.
    let (mut n, mut good) = (0, 0);
    for (z, t) in out.zbuffer.data().iter().zip(frame.true_color_depth.data()) {
        if z.is_finite() {
            n += 1;
            // 0.5 %: the depth change across one colour pixel on the steepest smooth surface
            // of the preset (the sphere's limb excluded by the 2 % of allowed misses).
            good += ((z - t).abs() <= 0.005 * t) as usize;
        }
    }
    let frac = good as f64 / n as f64;
    eprintln!("course z-buffer: {good}/{n} ({frac:.4})");
    // Guard and bar without a recorded measurement: n is most of the 640 × 480 colour view;
    // 0.98 leaves the 2 % of misses the comment above allows at edges and the sphere's limb.
    assert!(n > 50_000 && frac > 0.98, "{frac}");
}

#[test]
fn h5_removes_faces_across_jumps_and_keeps_smooth_faces() {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
    let step = 2;
    let mesh =
        fusion::mesh_from_depth(&frame.true_color_depth, &setup.rig.color, &frame.color, step);
    let clean = fusion::remove_stretched_faces(&mesh, FusionOptions::default().stretch_ratio);
    let kept: std::collections::HashSet<[u32; 3]> = clean.faces.iter().copied().collect();
    // Grid pixel of every vertex from its texture coordinate.
    let (cw, ch) = frame.color.size();
    let pixel = |i: u32| {
        let uv = mesh.uvs[i as usize];
        let x = (uv[0] * cw as f32 - 0.5).round() as usize;
        let y = ((1.0 - uv[1]) * ch as f32 - 0.5).round() as usize;
        y * cw + x
    };
    let (mut jumps, mut jumps_removed, mut smooth, mut smooth_kept) = (0, 0, 0, 0);
    for f in &mesh.faces {
        let z: Vec<f32> = f.iter().map(|&i| mesh.vertices[i as usize][2]).collect();
        let (lo, hi) = (
            z.iter().cloned().fold(f32::INFINITY, f32::min),
            z.iter().cloned().fold(0.0, f32::max),
        );
        if hi > 1.1 * lo {
            jumps += 1;
            jumps_removed += (!kept.contains(f)) as usize;
            continue;
        }
        let px: Vec<usize> = f.iter().map(|&i| pixel(i)).collect();
        let same_object = px
            .iter()
            .all(|&p| frame.true_color_object.data()[p] == frame.true_color_object.data()[px[0]]);
        // Smooth and facing the camera: true normals tilted < 38.7° (|n_xy| < 0.8 |n_z|), a
        // margin below the 45° of the default test for the facet-vs-surface normal difference.
        let facing = px.iter().all(|&p| {
            let n = frame.true_color_normal.data()[p];
            (n[0] * n[0] + n[1] * n[1]).sqrt() < 0.8 * n[2].abs()
        });
        if same_object && facing {
            smooth += 1;
            smooth_kept += kept.contains(f) as usize;
        }
    }
    eprintln!(
        "H5: {jumps_removed}/{jumps} jump faces removed, {smooth_kept}/{smooth} smooth faces kept"
    );
    // Bars: issue 2 (every face across a > 10 % jump removed, ≥ 99 % of smooth faces kept).
    // Measured (issue 5's report): 2790 of 2790 jump faces removed, 992 140 of 992 140 smooth
    // faces kept; 500 and 100 000 are guards well below those counts.
    assert!(jumps > 500, "the preset must have depth jumps, got {jumps} faces");
    assert_eq!(jumps_removed, jumps, "every face across a > 10 % jump must go");
    assert!(
        smooth > 100_000 && smooth_kept as f64 >= 0.99 * smooth as f64,
        "{smooth_kept}/{smooth}"
    );
}

/// Pixels within one pixel of a depth edge (> 2 % jump) of `truth` or of nothing.
fn edge_band(truth: &Image<f32>) -> Image<bool> {
    let (w, h) = truth.size();
    Image::from_fn(w, h, |x, y| {
        let z = *truth.get(x, y);
        (-1i32..=1).any(|dy| {
            (-1i32..=1).any(|dx| {
                let (sx, sy) = (x as i32 + dx, y as i32 + dy);
                if sx < 0 || sy < 0 || sx >= w as i32 || sy >= h as i32 {
                    return false;
                }
                let n = *truth.get(sx as usize, sy as usize);
                !(n.is_finite() && z.is_finite()) || (n - z).abs() > 0.02 * z.min(n)
            })
        })
    })
}

#[test]
fn distorted_input_equals_undistort_then_fuse() {
    // The same scene seen through the distorted rig and through its distortion-free twin
    // (what undistorting both images produces): the colour-frame depth of the first, looked
    // up at the undistorted position of each pixel in the second, must agree.
    let setup = synth::kinect_preset(false);
    let mut ideal = setup.clone();
    ideal.rig.depth = setup.rig.depth.without_distortion();
    ideal.rig.color = setup.rig.color.without_distortion();
    let opts = FusionOptions { linear: false, mesh_step: 8, ..FusionOptions::default() };
    let run = |s: &synth::SynthSetup| {
        let f = synth::render(s);
        let out = fusion::run(&s.rig, &f.depth, f.depth_kind, &f.color, &opts).unwrap();
        (f, out)
    };
    let (fd, od) = run(&setup);
    let (_, oi) = run(&ideal);
    let cam = setup.rig.color;
    let (w, h) = (cam.width, cam.height);
    let band = edge_band(&fd.true_color_depth);
    let (mut n, mut good) = (0, 0);
    for y in (0..h).step_by(2) {
        for x in (0..w).step_by(2) {
            let i = y * w + x;
            let zd = od.nearest.data()[i];
            if !zd.is_finite() || !fd.true_seen_by_depth.data()[i] || band.data()[i] {
                continue;
            }
            let Some(r) = cam.unproject(x as f64, y as f64) else { continue };
            let k = cam.intrinsics;
            let (ui, vi) = (k.fx * r.x + k.skew * r.y + k.cx, k.fy * r.y + k.cy);
            let (xi, yi) = ((ui + 0.5).floor(), (vi + 0.5).floor());
            if xi < 0.0 || yi < 0.0 || xi >= w as f64 || yi >= h as f64 {
                continue;
            }
            let zi = oi.nearest.data()[yi as usize * w + xi as usize];
            if !zi.is_finite() {
                // Outside the twin's depth footprint (the lenses' fields of view differ).
                continue;
            }
            n += 1;
            // 0.5 %: each side carries the nearest-fill error (< 0.5 px of surface slope)
            // plus up to 0.5 px of lookup rounding; on smooth surfaces that is < 0.3 %.
            good += ((zd - zi).abs() <= 0.005 * zd) as usize;
        }
    }
    let frac = good as f64 / n as f64;
    eprintln!("distorted vs undistorted: {good}/{n} within 0.5 % ({frac:.4})");
    // Measured 99.8 % (issue 5's report, "Distorted input"); n: a guard below the colour view.
    assert!(n > 300_000 && frac >= 0.99, "{frac}");
}

#[test]
fn bad_input_is_rejected_with_clear_errors() {
    let setup = synth::course_preset();
    let frame = synth::render(&setup);
    let opts = FusionOptions { linear: false, mesh_step: 8, ..FusionOptions::default() };
    let small = Image::filled(320, 240, 1.0f32);
    match fusion::run(&setup.rig, &small, DepthKind::Range, &frame.color, &opts) {
        Err(GeometryError::SizeMismatch {
            got_w: 320,
            got_h: 240,
            want_w: 640,
            want_h: 480,
            ..
        }) => {}
        other => panic!("expected a size mismatch, got {other:?}"),
    }
    let small_color = Image::filled(10, 10, [0u8; 3]);
    assert!(matches!(
        fusion::run(&setup.rig, &frame.depth, DepthKind::Range, &small_color, &opts),
        Err(GeometryError::SizeMismatch { .. })
    ));
    for bad in [f32::NAN, 0.0, -1.0] {
        let invalid = Image::filled(640, 480, bad);
        let err =
            fusion::run(&setup.rig, &invalid, DepthKind::Range, &frame.color, &opts).unwrap_err();
        assert!(matches!(err, GeometryError::InvalidInput(_)), "{err}");
        assert!(err.to_string().contains("no valid sample"), "{err}");
    }
    // NaN pixels are "no sample": a NaN band gives exactly that many fewer points, and no
    // point at the origin.
    let mut depth = frame.depth.clone();
    for y in 100..150 {
        for x in 0..640 {
            *depth.get_mut(x, y) = f32::NAN;
        }
    }
    let out = fusion::run(&setup.rig, &depth, DepthKind::Range, &frame.color, &opts).unwrap();
    // The course preset's 640 × 480 depth image minus the 50 NaN rows set above.
    assert_eq!(out.summary.valid_depth_pixels, 640 * 480 - 50 * 640);
    assert_eq!(out.cloud.len(), 640 * 480 - 50 * 640);
    assert!(out.cloud.points.iter().all(|p| p[2] > 1.0));
}
