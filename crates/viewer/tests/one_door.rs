//! One front door into fusion (issue 46): every door prepares its depth through
//! `geometry::fusion::Request::prepare_depth`, once. With the preparation broken
//! (`geometry::fusion::fault::break_depth_preparation`: every sample 2 % farther) each door —
//! a single frame (`fusion_gpu::fuse`, what `kfuse fuse` and Python's `kfuse.fuse` run),
//! several Kinects (`fusion_gpu::fuse_multi`, `kfuse fuse --rig RIG --sensor …`), a sequence
//! (`kfuse_sequence::process`, its decoder's preparation then its registration) and the
//! viewer's pipeline — must give exactly what it gives, sound, for depth that is 2 % farther:
//! a door that prepared its depth itself would not change, one that prepared it twice would
//! change by 4 %.
//!
//! One test in this binary: the fault switch is process-wide.

use fusion_gpu::Engine;
use geometry::fusion::multi::SensorImages;
use geometry::fusion::{self, FusionOptions};
use geometry::{DepthKind, Image, synth};
use kfuse_sequence::process::{Decoded, Extras, Processor};
use kfuse_sequence::write::KFUSE_UNITS_PER_METRE;
use viewer::data::Frame;
use viewer::pipeline::{self, Toggles};

/// What the broken preparation does to a depth image (the fault's own arithmetic, f32).
fn farther(depth: &Image<f32>) -> Image<f32> {
    depth.map(|&z| z * 1.02)
}

/// Bit patterns of a z-buffer, so NaN compares equal to NaN.
fn bits(z: &Image<f32>) -> Vec<u32> {
    z.data().iter().map(|v| v.to_bits()).collect()
}

fn single(rig: &geometry::Rig, depth: &Image<f32>, color: &Image<[u8; 3]>) -> Vec<u32> {
    let (out, _) =
        fusion_gpu::fuse(Engine::Cpu, rig, depth, DepthKind::Z, color, &FusionOptions::default())
            .expect("single-frame fuse");
    bits(&out.zbuffer)
}

fn multi(ring: &synth::KinectRing, depths: &[Image<f32>], colors: &[Image<[u8; 3]>]) -> Vec<u32> {
    let inputs: Vec<SensorImages> = ring
        .serials
        .iter()
        .zip(depths.iter().zip(colors))
        .map(|(s, (d, c))| SensorImages { sensor: s.clone(), depth: d.clone(), color: c.clone() })
        .collect();
    let view = ring.rig.camera(&format!("{}.color", ring.serials[0])).expect("a colour camera");
    let (_, zbuffer, _) = fusion_gpu::fuse_multi(
        Engine::Cpu,
        &ring.rig,
        &inputs,
        DepthKind::Z,
        &FusionOptions::default(),
        view,
    )
    .expect("several Kinects");
    bits(&zbuffer)
}

fn sequence(rig: &geometry::Rig, depth: &Image<f32>, color: &Image<[u8; 3]>) -> Vec<u16> {
    let extras = Extras { holes: true, color_on_depth: false, cloud: false, color_valid: false };
    let (engine, _) = Engine::Cpu.open().expect("engine");
    let options = FusionOptions::default();
    let mut p = Processor::new(rig, None, extras, KFUSE_UNITS_PER_METRE, &options, engine)
        .expect("processor");
    // A decoded frame as a bag gives it (metres, little-endian f32), prepared by the decoder.
    let bytes: Vec<u8> = depth.data().iter().flat_map(|v| v.to_le_bytes()).collect();
    let (w, h) = depth.size();
    let depth = p.decoding.take_decoded(&bytes, w, h).expect("decoded frame");
    let decoded = Decoded { depth, raw: None, color: Some(color.clone()), sensor: None };
    let mut r = p.registering.register(std::slice::from_ref(&decoded)).expect("register");
    r.pop().expect("one frame").depth_units
}

fn viewer(rig: &geometry::Rig, depth: &Image<f32>, color: &Image<[u8; 3]>) -> Vec<u32> {
    let frame = Frame {
        name: "synthetic".into(),
        rig: rig.clone(),
        depth: depth.clone(),
        kind: DepthKind::Z,
        color: color.clone(),
        ir: None,
    };
    let fused = pipeline::fuse(&frame, Toggles::default(), None).expect("viewer fusion");
    bits(&fused.output.zbuffer)
}

#[test]
fn a_broken_depth_preparation_changes_every_door_alike() {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
    assert_eq!(frame.depth_kind, DepthKind::Z);
    let (rig, depth, color) = (&setup.rig, &frame.depth, &frame.color);
    let ring = synth::kinect_ring_preset();
    let ring_frames = synth::render_ring(&ring, None);
    let ring_depths: Vec<Image<f32>> = ring_frames.iter().map(|f| f.depth.clone()).collect();
    let ring_farther: Vec<Image<f32>> = ring_depths.iter().map(farther).collect();
    let ring_colors: Vec<Image<[u8; 3]>> = ring_frames.iter().map(|f| f.color.clone()).collect();

    fusion::fault::break_depth_preparation(false);
    let sound = (
        single(rig, depth, color),
        multi(&ring, &ring_depths, &ring_colors),
        sequence(rig, depth, color),
        viewer(rig, depth, color),
    );
    let sound_farther = (
        single(rig, &farther(depth), color),
        multi(&ring, &ring_farther, &ring_colors),
        sequence(rig, &farther(depth), color),
        viewer(rig, &farther(depth), color),
    );
    fusion::fault::break_depth_preparation(true);
    let broken = (
        single(rig, depth, color),
        multi(&ring, &ring_depths, &ring_colors),
        sequence(rig, depth, color),
        viewer(rig, depth, color),
    );
    fusion::fault::break_depth_preparation(false);

    let changed = |a: &[u32], b: &[u32]| a.iter().zip(b).filter(|(x, y)| x != y).count();
    eprintln!(
        "z-buffer pixels changed by the fault: single {}, several Kinects {}, sequence {}, viewer {}",
        changed(&sound.0, &broken.0),
        changed(&sound.1, &broken.1),
        sound.2.iter().zip(&broken.2).filter(|(x, y)| x != y).count(),
        changed(&sound.3, &broken.3),
    );
    // The fault is visible at every door...
    assert!(broken.0 != sound.0, "single frame: the fault changed nothing");
    assert!(broken.1 != sound.1, "several Kinects: the fault changed nothing");
    assert!(broken.2 != sound.2, "sequence: the fault changed nothing");
    assert!(broken.3 != sound.3, "viewer: the fault changed nothing");
    // ...and is exactly one preparation of the depth, at every door.
    assert!(broken.0 == sound_farther.0, "single frame: not prepared exactly once");
    assert!(broken.1 == sound_farther.1, "several Kinects: not prepared exactly once");
    assert!(broken.2 == sound_farther.2, "sequence: not prepared exactly once");
    assert!(broken.3 == sound_farther.3, "viewer: not prepared exactly once");
    // The viewer and the single frame are the same door.
    assert!(broken.3 == broken.0, "viewer and single frame differ");
}
