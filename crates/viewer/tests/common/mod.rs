//! Shared fixtures of the viewer tests.
#![allow(dead_code)]

use std::sync::OnceLock;

use geometry::synth::{self, SynthFrame};
use viewer::data::Frame;

/// The synthetic Kinect scene with its truths, rendered once per test binary.
pub fn synth_frame() -> &'static (Frame, SynthFrame) {
    static FRAME: OnceLock<(Frame, SynthFrame)> = OnceLock::new();
    FRAME.get_or_init(|| {
        let setup = synth::kinect_preset(true);
        let truth = synth::render(&setup);
        let frame = Frame {
            name: "synthetic Kinect v2 scene".into(),
            rig: setup.rig.clone(),
            depth: truth.depth.clone(),
            kind: truth.depth_kind,
            color: truth.color.clone(),
            ir: Some(truth.amplitude.clone()),
        };
        (frame, truth)
    })
}

/// True when a wgpu adapter exists. Without one: panics when `KFUSE_REQUIRE_GPU=1` (CI), else
/// prints a SKIP line for `test` and returns false.
pub fn gpu_available(test: &str) -> bool {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let ok = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions::default()))
        .is_ok();
    if !ok {
        if std::env::var("KFUSE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
            panic!(
                "{test}: KFUSE_REQUIRE_GPU=1 but no wgpu adapter was found (install mesa-vulkan-drivers for lavapipe)"
            );
        }
        test_skip::skip(test, "no wgpu adapter");
    }
    ok
}
