//! One pipeline for frames and sequences (issue 30): a sequence's per-pixel stages are those of
//! a single frame, on the same engine, with the same parameters. The synthetic Kinect frame
//! (`geometry::synth::kinect_preset`, a scene with disocclusions) goes through
//! `geometry::fusion::run` (what `kfuse fuse` runs on one frame) and through the sequence's
//! `Processor::register` (what `kfuse fuse --recording/--frames` runs per frame), first as
//! built, then with one wiring step broken (`geometry::fusion::fault`: H8's growth radius
//! dropped in `PixelParams::new`). Both paths must agree bit for bit in both states, and the
//! broken state must differ from the sound one: a sequence path that wired its stages itself
//! (as `process.rs` did before, with its own radii) would keep the sound mask and fail here.
//!
//! One test in this binary: the fault switch is process-wide.

use fusion_gpu::{Engine, EngineUsed};
use geometry::fusion::{self, FusionOptions};
use geometry::{DepthKind, Image, synth};
use kfuse_sequence::process::{Decoded, Extras, Processor};
use kfuse_sequence::write::KFUSE_UNITS_PER_METRE;

/// The outputs both paths give for one frame: H7 as the sequence writes it (16-bit
/// millimetres, `to_units`), H8's mask (255 = hole) and H6's colour.
#[derive(PartialEq)]
struct Outputs {
    depth_units: Vec<u16>,
    holes: Vec<u8>,
    color_on_depth: Image<[u8; 3]>,
}

fn single_frame(frame: &synth::SynthFrame, rig: &geometry::Rig, engine: Engine) -> Outputs {
    let (out, _) = fusion_gpu::fuse(
        engine,
        rig,
        &frame.depth,
        DepthKind::Z,
        &frame.color,
        &FusionOptions::default(),
    )
    .expect("single-frame fuse");
    Outputs {
        depth_units: kfuse_sequence::process::to_units(out.zbuffer.data(), KFUSE_UNITS_PER_METRE),
        holes: out.hole_mask.data().iter().map(|&h| if h { 255 } else { 0 }).collect(),
        color_on_depth: out.color_on_depth,
    }
}

fn sequence(frame: &synth::SynthFrame, rig: &geometry::Rig, engine: Engine) -> Outputs {
    let extras = Extras { holes: true, color_on_depth: true, cloud: false, color_valid: false };
    let (opened, _) = engine.open().expect("engine");
    let options = FusionOptions::default();
    let mut p = Processor::new(rig, None, extras, KFUSE_UNITS_PER_METRE, &options, opened)
        .expect("processor");
    // NaN (no sample) as 0, the decoder's and the frame folder reader's convention.
    let depth = frame.depth.map(|&z| if z > 0.0 { z } else { 0.0 });
    let decoded = Decoded { depth, raw: None, color: Some(frame.color.clone()), sensor: None };
    let mut r = p.registering.register(std::slice::from_ref(&decoded)).expect("sequence register");
    let r = r.pop().expect("one frame");
    Outputs {
        depth_units: r.depth_units,
        holes: r.holes.expect("holes asked for"),
        color_on_depth: r.color_on_depth.expect("colour on depth asked for"),
    }
}

fn holes(o: &Outputs) -> usize {
    o.holes.iter().filter(|&&h| h == 255).count()
}

#[test]
fn a_broken_stage_breaks_the_single_frame_and_the_sequence_path_alike() {
    let setup = synth::kinect_preset(false);
    let frame = synth::render(&setup);
    assert_eq!(frame.depth_kind, DepthKind::Z, "a Kinect's depth is z");
    let rig = &setup.rig;
    let mut engines = vec![Engine::Cpu];
    match Engine::Gpu.open() {
        Ok((_, EngineUsed::Gpu { adapter, .. })) => {
            eprintln!("GPU: {adapter}");
            engines.push(Engine::Gpu);
        }
        Ok(_) => unreachable!("Engine::Gpu opens a GPU or fails"),
        Err(e) => {
            assert!(
                std::env::var("KFUSE_REQUIRE_GPU").map_or(true, |v| v != "1"),
                "no GPU in CI: {e}"
            );
            test_skip::skip("one_pipeline (GPU half)", &e.to_string());
        }
    }
    for engine in engines {
        fusion::fault::break_hole_growth(false);
        let (single_sound, seq_sound) =
            (single_frame(&frame, rig, engine), sequence(&frame, rig, engine));
        fusion::fault::break_hole_growth(true);
        let (single_broken, seq_broken) =
            (single_frame(&frame, rig, engine), sequence(&frame, rig, engine));
        fusion::fault::break_hole_growth(false);
        eprintln!(
            "{engine}: hole pixels sound {} (single) / {} (sequence), broken {} / {}",
            holes(&single_sound),
            holes(&seq_sound),
            holes(&single_broken),
            holes(&seq_broken)
        );
        // The frame has disocclusions, and growth is part of the mask: the fault is visible.
        assert!(holes(&single_sound) > 0, "{engine}: the scene has no hole");
        assert!(single_broken.holes != single_sound.holes, "{engine}: the fault changed nothing");
        // Both paths give the same outputs, sound or broken.
        assert!(
            seq_sound == single_sound,
            "{engine}: sound sequence differs from the single frame"
        );
        assert!(
            seq_broken == single_broken,
            "{engine}: broken sequence differs from the single frame"
        );
        // Only H8 was broken: H7 and H6 are unchanged.
        assert_eq!(seq_broken.depth_units, seq_sound.depth_units, "{engine}: H7");
        assert!(seq_broken.color_on_depth == seq_sound.color_on_depth, "{engine}: H6");
    }
}
