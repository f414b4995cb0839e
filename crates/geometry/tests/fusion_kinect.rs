//! Acceptance tests of the fusion pipeline against the Kinect preset's ground truth.

use geometry::Image;
use geometry::fusion::{self, FusionOptions};
use geometry::synth::{self, SynthFrame};

/// Relative depth difference within a 3×3 neighbourhood that marks a true depth edge: 2 %
/// is far above the change between neighbouring pixels on any smooth surface of the preset
/// (< 0.5 %) and below every object/background gap (> 20 %).
const EDGE_JUMP: f32 = 0.02;

/// Pixels of `truth` (NaN = nothing) next to a depth edge or nothing: the 1-pixel band
/// excluded by the acceptance criteria.
fn edge_band(truth: &Image<f32>) -> Image<bool> {
    let (w, h) = truth.size();
    Image::from_fn(w, h, |x, y| {
        let z = *truth.get(x, y);
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let (sx, sy) = (x as i32 + dx, y as i32 + dy);
                if sx < 0 || sy < 0 || sx >= w as i32 || sy >= h as i32 {
                    continue;
                }
                let n = *truth.get(sx as usize, sy as usize);
                if !(n.is_finite() && z.is_finite()) || (n - z).abs() > EDGE_JUMP * z.min(n) {
                    return true;
                }
            }
        }
        false
    })
}

fn kinect() -> (geometry::synth::SynthSetup, SynthFrame, fusion::FusionOutput) {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
    let out = fusion::run(
        &setup.rig,
        &frame.depth,
        frame.depth_kind,
        &frame.color,
        &FusionOptions::default(),
    )
    .unwrap();
    (setup, frame, out)
}

#[test]
fn kinect_noise_free_meets_the_acceptance_bars() {
    let (_setup, frame, out) = kinect();

    // 1. Z-buffered depth (H7 + H3 nearest) vs the true colour-frame depth, on colour pixels
    //    both cameras see, 1-pixel band at depth edges excluded. Bar: 0.5 % on >= 99 %.
    let band = edge_band(&frame.true_color_depth);
    let (mut n, mut good) = (0usize, 0usize);
    for i in 0..band.data().len() {
        if !frame.true_seen_by_depth.data()[i] || band.data()[i] {
            continue;
        }
        n += 1;
        let (got, want) = (out.nearest.data()[i], frame.true_color_depth.data()[i]);
        good += ((got - want).abs() <= 0.005 * want) as usize;
    }
    let frac = good as f64 / n as f64;
    eprintln!("z-buffer: {good}/{n} within 0.5 % ({frac:.5})");
    // Bars: issue 2's acceptance criteria. Measured (issue 5's report): 99.74 % of 1.57 M
    // pixels; the 1 000 000 floor only guards against a shrunken common view.
    assert!(n > 1_000_000, "the preset must have a large common view, got {n} pixels");
    assert!(frac >= 0.99, "z-buffered depth within 0.5 % on only {frac:.4} of the common view");

    // 2. Hole mask vs the true disocclusion mask. Bar: IoU >= 0.9.
    let (mut inter, mut union) = (0usize, 0usize);
    for (m, t) in out.hole_mask.data().iter().zip(frame.true_disocclusion.data()) {
        inter += (*m && *t) as usize;
        union += (*m || *t) as usize;
    }
    let iou = inter as f64 / union as f64;
    eprintln!("holes: IoU {iou:.4} ({inter}/{union})");
    // Bar: issue 2 (IoU ≥ 0.9); measured IoU 0.924 (issue 5). 5 000: a guard that the preset
    // has disocclusions at all.
    assert!(union > 5_000, "the preset must have real disocclusions, got {union} pixels");
    assert!(iou >= 0.9, "hole mask IoU {iou:.4}");

    // 3. Plane-filled holes on the background (object 0). Bar: every one within 0.5 %.
    let (mut nb, mut worst) = (0usize, 0f32);
    for i in 0..band.data().len() {
        if out.hole_mask.data()[i] && frame.true_color_object.data()[i] == 0 {
            nb += 1;
            let (got, want) = (out.filled.data()[i], frame.true_color_depth.data()[i]);
            worst = worst.max((got - want).abs() / want);
        }
    }
    eprintln!("plane fill: {nb} background hole pixels, worst relative error {worst:.2e}");
    // Bar: issue 2 (0.5 %); measured worst 3.1e-5 over 20 118 pixels (issue 5), so 5 000 is a
    // guard at a quarter of the measured count.
    assert!(nb > 5_000 && worst <= 0.005, "{nb} pixels, worst {worst}");

    // 4. H6 colour on the depth grid vs the true colour, on depth pixels with a sample whose
    //    point the colour camera sees, 1-pixel band at depth edges excluded.
    //    Bar: within 2/255 on >= 99 % (bilinear on smooth textures: < 1 level of
    //    interpolation error plus 0.5 of rounding on each side).
    let dband = edge_band(&frame.true_depth_z);
    let (mut nc, mut gc) = (0usize, 0usize);
    for i in 0..dband.data().len() {
        if !frame.true_seen_by_color.data()[i] || dband.data()[i] || frame.depth.data()[i].is_nan()
        {
            continue;
        }
        nc += 1;
        let ok = out.color_on_depth_valid.data()[i]
            && out.color_on_depth.data()[i]
                .iter()
                .zip(frame.true_color_on_depth.data()[i])
                .all(|(a, b)| a.abs_diff(b) <= 2);
        gc += ok as usize;
    }
    let cfrac = gc as f64 / nc as f64;
    eprintln!("H6: {gc}/{nc} within 2/255 ({cfrac:.5})");
    // Bar: issue 2 (2/255 on ≥ 99 %); measured 99.7 % (issue 5). 100 000: a guard below the
    // preset's 217 088 depth pixels, most of which the colour camera sees.
    assert!(nc > 100_000 && cfrac >= 0.99, "H6 colour within 2/255 on only {cfrac:.4}");
}
