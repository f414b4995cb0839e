//! The work of the fusion stages is bounded before it starts (issue 12): a coverage radius or a
//! rig focal length that would size the nearest fill's disc table, the hole mask or the linear
//! resampling beyond the documented limits is one clear error, not a hang or an abort.

use geometry::fusion::{
    self, FusionOptions, MAX_COVERAGE_RADIUS_PX, MAX_SAMPLE_SPACING_PX, Registration,
};
use geometry::{
    CameraModel, DepthKind, Distortion, GeometryError, Image, Intrinsics, Rig, RigidTransform,
};
use nalgebra::{Rotation3, Vector3};

/// A 64x48 depth camera and a 96x72 colour camera 5 cm to the side: sample spacing 1.5 px.
fn small_rig(depth_f: f64) -> Rig {
    let depth =
        CameraModel::new(64, 48, Intrinsics::new(depth_f, depth_f, 31.5, 23.5), Distortion::NONE);
    let color = CameraModel::new(96, 72, Intrinsics::new(90.0, 90.0, 47.5, 35.5), Distortion::NONE);
    Rig::new(
        depth,
        color,
        RigidTransform::new(Rotation3::identity(), Vector3::new(-0.05, 0.0, 0.0)),
    )
}

fn small_frame() -> (Image<f32>, Image<[u8; 3]>) {
    let depth = Image::from_fn(64, 48, |x, _| 1.5 + 0.01 * x as f32);
    let color = Image::from_fn(96, 72, |x, y| [x as u8, y as u8, 100]);
    (depth, color)
}

fn with_factor(factor: f32) -> FusionOptions {
    FusionOptions { hole_radius_factor: factor, linear: false, ..FusionOptions::default() }
}

#[test]
fn coverage_radius_limit_is_exact_at_the_boundary_and_fusion_runs_up_to_it() {
    let rig = small_rig(60.0);
    let spacing = fusion::sample_spacing_px(&rig);
    // Hand calculation: colour f 90 px / depth f 60 px = 1.5 colour px per depth sample; 1e-6:
    // f32 rounding of the ratio.
    assert!((spacing - 1.5).abs() < 1e-6, "spacing {spacing}");
    let (depth, color) = small_frame();
    // The largest factor allowed gives exactly the limit and fuses.
    let at_limit = with_factor(MAX_COVERAGE_RADIUS_PX / spacing);
    let r = fusion::checked_coverage_radius_px(&rig, &at_limit).expect("radius at the limit");
    assert_eq!(r, MAX_COVERAGE_RADIUS_PX);
    let out = fusion::run(&rig, &depth, DepthKind::Z, &color, &at_limit).expect("fuses");
    assert_eq!(out.summary.coverage_radius_px, MAX_COVERAGE_RADIUS_PX);
    // Every pixel of the 64 × 48 depth image (1.5 + 0.01 x m) is a valid sample.
    assert_eq!(out.summary.points, 64 * 48);
    // One ulp more is refused, by the library and by the streaming workspace.
    let above = with_factor((MAX_COVERAGE_RADIUS_PX / spacing).next_up());
    let e = fusion::run(&rig, &depth, DepthKind::Z, &color, &above).unwrap_err();
    let message = e.to_string();
    assert!(matches!(e, GeometryError::InvalidInput(_)), "{e:?}");
    // 16 px: MAX_COVERAGE_RADIUS_PX; 10.67 = 16 / the rig's 1.5 px spacing.
    assert!(message.contains("16 px") && message.contains("at most 10.67"), "{message}");
    let e = Registration::new(&rig, DepthKind::Z, &above).map(|_| ()).unwrap_err();
    assert!(matches!(e, GeometryError::InvalidInput(_)), "{e:?}");
}

#[test]
fn hole_radius_factors_that_hung_or_aborted_are_refused_at_once() {
    // 30 made a 4 000-offset disc per colour pixel (hours); 1e9 an offset table of ~10^19
    // entries (abort). Both now fail before any allocation.
    let rig = small_rig(60.0);
    let (depth, color) = small_frame();
    for factor in [30.0, 1e9, f32::INFINITY, f32::NAN, 0.0, -1.0] {
        let e = fusion::run(&rig, &depth, DepthKind::Z, &color, &with_factor(factor))
            .expect_err("refused");
        assert!(matches!(e, GeometryError::InvalidInput(_)), "{factor}: {e:?}");
        let e =
            Registration::new(&rig, DepthKind::Z, &with_factor(factor)).map(|_| ()).unwrap_err();
        assert!(matches!(e, GeometryError::InvalidInput(_)), "{factor}: {e:?}");
    }
}

#[test]
fn depth_focal_lengths_in_millimetres_or_metres_are_refused_with_the_fix() {
    let (depth, color) = small_frame();
    // 3.65 (mm) hung in the nearest fill; 0.00365 (m) took all memory. The spacing at the
    // limit itself (colour 90 px / depth 11.25 px = 8) is still a rig.
    for f in [3.65, 0.00365, 1e-300] {
        let rig = small_rig(f);
        let e = fusion::run(&rig, &depth, DepthKind::Z, &color, &with_factor(1.2))
            .expect_err("refused");
        let message = e.to_string();
        assert!(matches!(e, GeometryError::InvalidParameter(_)), "{f}: {e:?}");
        assert!(message.contains("in pixels"), "{message}");
        let e = Registration::new(&rig, DepthKind::Z, &with_factor(1.2)).map(|_| ()).unwrap_err();
        assert!(matches!(e, GeometryError::InvalidParameter(_)), "{f}: {e:?}");
    }
    let rig = small_rig(90.0 / MAX_SAMPLE_SPACING_PX as f64);
    assert_eq!(fusion::sample_spacing_px(&rig), MAX_SAMPLE_SPACING_PX);
    let r = fusion::checked_coverage_radius_px(&rig, &with_factor(1.2)).expect("spacing 8 ok");
    // Hand calculation: factor 1.2 × MAX_SAMPLE_SPACING_PX (8) = 9.6 px; 1e-5: f32 rounding.
    assert!((r - 9.6).abs() < 1e-5, "{r}");
}

#[test]
fn registration_from_parts_bounds_its_radii() {
    let rig = small_rig(60.0);
    let proj = fusion::ColorProjection::from_rig(&rig);
    let rays = fusion::depth_ray_table(&rig.depth, DepthKind::Z);
    let ok = Registration::from_parts(proj, &rays, 64, MAX_COVERAGE_RADIUS_PX, 0.0);
    assert!(ok.is_ok());
    for (r, g) in
        [(MAX_COVERAGE_RADIUS_PX.next_up(), 1.0), (2.0, 1e9), (f32::NAN, 1.0), (-1.0, 1.0)]
    {
        let e = Registration::from_parts(proj, &rays, 64, r, g).map(|_| ()).unwrap_err();
        assert!(matches!(e, GeometryError::InvalidInput(_)), "{r} {g}: {e:?}");
    }
}
