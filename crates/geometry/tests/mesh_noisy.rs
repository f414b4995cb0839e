//! H4 on the depth grid and H5's sample-scale rule on the noisy Kinect preset
//! (`synth::kinect_noisy_preset`: σ = 1.5 mm · z², flying pixels at depth edges), against the
//! scene's truth: which object every depth pixel sees and which pixels fly.

use geometry::fusion::{self, EdgeFaceRule, FusionOptions, MeshSource};
use geometry::{Mesh, synth};

struct Case {
    setup: synth::SynthSetup,
    noisy: synth::NoisyFrame,
    out: fusion::FusionOutput,
    opts: FusionOptions,
}

fn case() -> Case {
    let (setup, noise) = synth::kinect_noisy_preset();
    let noisy = synth::render_noisy(&setup, &noise);
    let opts = FusionOptions { linear: false, ..FusionOptions::default() };
    let f = &noisy.frame;
    let out = fusion::run(&setup.rig, &f.depth, f.depth_kind, &f.color, &opts).unwrap();
    Case { setup, noisy, out, opts }
}

/// Counts of one H5 run over the depth-grid mesh: (bridging faces, bridging removed,
/// continuous faces, continuous kept). A face *bridges* when its vertices' depth pixels see
/// different objects or one of them is a flying pixel; otherwise it lies on one continuous
/// surface.
fn classify(c: &Case, mesh: &Mesh, pixels: &[u32], clean: &Mesh) -> (usize, usize, usize, usize) {
    let kept: std::collections::HashSet<[u32; 3]> = clean.faces.iter().copied().collect();
    let object = c.noisy.frame.true_depth_object.data();
    let flying = c.noisy.flying.data();
    let (mut bridge, mut bridge_removed, mut cont, mut cont_kept) = (0, 0, 0, 0);
    for f in &mesh.faces {
        let px = f.map(|v| pixels[v as usize] as usize);
        let same = px.iter().all(|&p| object[p] == object[px[0]]);
        if !same || px.iter().any(|&p| flying[p]) {
            bridge += 1;
            bridge_removed += !kept.contains(f) as usize;
        } else {
            cont += 1;
            cont_kept += kept.contains(f) as usize;
        }
    }
    (bridge, bridge_removed, cont, cont_kept)
}

#[test]
fn h5_removes_every_face_across_a_jump_and_keeps_the_continuous_surfaces() {
    let c = case();
    let rig = &c.setup.rig;
    let (mesh, pixels) = fusion::mesh_on_depth_grid(
        rig.depth.width,
        rig.depth.height,
        &c.out.cloud.points,
        &c.out.cloud_pixels,
        &c.out.samples,
        &rig.color_from_depth,
        c.noisy.frame.color.size(),
        &c.out.color_on_depth,
        &c.out.color_on_depth_valid,
    );
    // The pipeline's default H4 is this mesh, and its summary reports H5's removed fraction.
    assert_eq!(c.opts.mesh_source, MeshSource::DepthGrid);
    assert_eq!(mesh, c.out.mesh);
    let s = &c.out.summary;
    assert_eq!(s.faces_before, mesh.faces.len());
    let expected = 1.0 - s.faces_after as f64 / s.faces_before as f64;
    assert!((s.faces_removed_fraction - expected).abs() < 1e-12);

    let robust = fusion::stretch_test(rig, &c.opts);
    assert_eq!(robust.rule, EdgeFaceRule::SampleScale);
    let clean = fusion::remove_edge_faces(&mesh, &robust);
    assert_eq!(clean.faces, c.out.mesh_clean.faces);
    let (bridge, bridge_removed, cont, cont_kept) = classify(&c, &mesh, &pixels, &clean);
    let kept = cont_kept as f64 / cont as f64;
    eprintln!(
        "sample-scale H5: removed {:.2} % of {} faces; {bridge_removed}/{bridge} bridging faces \
         removed, {cont_kept}/{cont} continuous kept ({:.2} %)",
        100.0 * s.faces_removed_fraction,
        s.faces_before,
        100.0 * kept
    );
    // The preset's outlines (box, sphere, cone against the wall and each other, every gap
    // ≥ 0.3 m) give thousands of bridging faces; every one must go.
    assert!(bridge > 2500, "{bridge} bridging faces");
    assert_eq!(bridge_removed, bridge, "faces across a depth jump survived H5");
    assert!(cont > 300_000, "{cont}");
    assert!(kept >= 0.95, "kept {kept:.4} of the continuous faces");

    // The handout's literal rule on the same noisy mesh: it, too, cuts the jumps, but the
    // noise tilts a large share of the faces on the flat wall past 45°.
    let literal = FusionOptions { edge_rule: EdgeFaceRule::Normal, ..c.opts };
    let clean_literal = fusion::remove_edge_faces(&mesh, &fusion::stretch_test(rig, &literal));
    let (_, _, cont_l, cont_kept_l) = classify(&c, &mesh, &pixels, &clean_literal);
    let kept_l = cont_kept_l as f64 / cont_l as f64;
    eprintln!(
        "literal normal rule: {cont_kept_l}/{cont_l} continuous kept ({:.2} %)",
        100.0 * kept_l
    );
    assert!(kept_l < 0.9, "the literal rule kept {kept_l:.4}: the preset is not noisy enough");
}

#[test]
fn colour_grid_meshes_of_noisy_depth_survive_the_sample_scale_rule() {
    // The old H4 (nearest fill on the colour grid, a staircase) with either H5 rule: the
    // sample-scale rule forgives the one-sample risers, the normal rule does not.
    let c = case();
    let rig = &c.setup.rig;
    let f = &c.noisy.frame;
    let removed = |rule: EdgeFaceRule| {
        let opts = FusionOptions { mesh_source: MeshSource::Nearest, edge_rule: rule, ..c.opts };
        let out = fusion::run(rig, &f.depth, f.depth_kind, &f.color, &opts).unwrap();
        out.summary.faces_removed_fraction
    };
    let (robust, literal) = (removed(EdgeFaceRule::SampleScale), removed(EdgeFaceRule::Normal));
    eprintln!(
        "colour grid, nearest: removed {:.2} % (sample scale), {:.2} % (normal)",
        100.0 * robust,
        100.0 * literal
    );
    // The scene's objects cover ~20 % of the view; their outlines are a few % of the faces.
    assert!(robust < 0.05, "{robust}");
    assert!(literal > 2.0 * robust, "{literal} vs {robust}");
}
