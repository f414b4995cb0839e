//! The viewer's depth-range slider (issue 46) is `kfuse fuse --depth-range`: with the range
//! set in its toggles, the pipeline keeps exactly the samples inside (counted here from the
//! frame's depth) and gives what `geometry::fusion::run` gives with that range.

use geometry::fusion::{self, DepthRange};
use viewer::data::demo_frame;
use viewer::pipeline::{self, Toggles};

#[test]
fn the_depth_range_toggle_keeps_the_samples_inside() {
    let frame = demo_frame();
    let is_sample = |z: f32| z.is_finite() && z > 0.0;
    let data = frame.depth.data();
    // From the 30th to the 70th percentile of the frame's samples: both ends cut the scene.
    let mut sorted: Vec<f32> = data.iter().copied().filter(|&z| is_sample(z)).collect();
    sorted.sort_by(f32::total_cmp);
    let n = sorted.len();
    let range = DepthRange::new(sorted[n * 3 / 10], sorted[n * 7 / 10]).unwrap();
    let all = data.iter().filter(|&&z| is_sample(z)).count();
    let inside =
        data.iter().filter(|&&z| is_sample(z) && (range.min_m..=range.max_m).contains(&z)).count();
    eprintln!("{inside} of {all} samples within {range}");
    assert!(inside > all / 3 && inside < all * 2 / 3, "{inside} of {all}");
    let toggles = Toggles { depth_range: range, ..Toggles::default() };
    let fused = pipeline::fuse(&frame, toggles, None).unwrap();
    assert_eq!(fused.output.summary.valid_depth_pixels, inside);
    let direct =
        fusion::run(&frame.rig, &frame.depth, frame.kind, &frame.color, &toggles.options())
            .unwrap();
    let bits = |z: &geometry::Image<f32>| z.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert!(bits(&fused.output.zbuffer) == bits(&direct.zbuffer));
    let whole = pipeline::fuse(&frame, Toggles::default(), None).unwrap();
    assert_eq!(whole.output.summary.valid_depth_pixels, all);
}
