//! Shared helpers of the GPU tests: the adapter policy and test rigs.
#![allow(dead_code)]

use fusion_gpu::{FusionContext, GpuError};

/// A context on the default adapter, or `None` (after printing `SKIP <test>: no GPU adapter`)
/// when there is none. With `KFUSE_REQUIRE_GPU=1` (CI) a missing adapter fails the test.
pub fn context_or_skip(test: &str) -> Option<FusionContext> {
    match FusionContext::new() {
        Ok(ctx) => {
            eprintln!("{test}: adapter {}", ctx.adapter_summary());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            if std::env::var("KFUSE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("{test}: KFUSE_REQUIRE_GPU=1 but {e}");
            }
            test_skip::skip(test, &format!("no GPU adapter ({e})"));
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

use std::sync::OnceLock;

use geometry::synth::{self, SynthFrame, SynthSetup};
use geometry::{CameraModel, Intrinsics, Rig};

/// The course preset (range depth, `synthdata.mat`-like rig), rendered once per test binary.
pub fn course() -> &'static (SynthSetup, SynthFrame) {
    static FRAME: OnceLock<(SynthSetup, SynthFrame)> = OnceLock::new();
    FRAME.get_or_init(|| {
        let setup = synth::course_preset();
        let frame = synth::render(&setup);
        (setup, frame)
    })
}

/// The Kinect preset (z depth, 512x424 -> 1920x1080, with sensor noise), rendered once.
pub fn kinect() -> &'static (SynthSetup, SynthFrame) {
    static FRAME: OnceLock<(SynthSetup, SynthFrame)> = OnceLock::new();
    FRAME.get_or_init(|| {
        let setup = synth::kinect_preset(true);
        let frame = synth::render(&setup);
        (setup, frame)
    })
}

/// `rig` with its colour camera scaled to `width` pixels wide (same field of view).
pub fn with_small_color(rig: &Rig, width: usize) -> Rig {
    let c = rig.color;
    let s = width as f64 / c.width as f64;
    let height = (c.height as f64 * s).round() as usize;
    let k = c.intrinsics;
    let intrinsics = Intrinsics {
        fx: k.fx * s,
        fy: k.fy * s,
        cx: (k.cx + 0.5) * s - 0.5,
        cy: (k.cy + 0.5) * s - 0.5,
        skew: k.skew * s,
    };
    let mut out = rig.clone();
    out.color = CameraModel::new(width, height, intrinsics, c.distortion);
    out
}
