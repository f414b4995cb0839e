//! Where a calibration run's time goes: the stage names of `kfuse calibrate`'s timing report,
//! the fits' own split ([`MonoCalibration::timings`], [`StereoCalibration::timings`]) laid out
//! as one flat list of stages that do not overlap, and `report.json`'s `timings_ms` section.
//!
//! The stages are wall-clock milliseconds on the thread that runs the calibration, in the
//! order they ran; nothing overlaps, so their sum is at most the run's wall time. Per image, the
//! read-and-decode and detection times are each image's own pool thread's wall time: images
//! are read and detected in parallel, so those sums can exceed their stage's wall time.

use geometry::timing::Timings;
use serde_json::{Value, json};

use crate::io::ImageTiming;
use crate::mono::{STAGE_FIT, STAGE_FIX_CHECKS, STAGE_SIGMA};
use crate::stereo::{STAGE_MONO_COLOR, STAGE_MONO_DEPTH};
use crate::{MonoCalibration, StereoCalibration};

/// Stage: σ of every fit's parameters, (JᵀJ)⁻¹ of each final solution.
pub const SIGMA: &str = "σ (uncertainty)";
/// Stage: the constraint checks' free fits (with constraint flags only).
pub const FIX_CHECKS: &str = "constraint checks";
/// Stage: the joint stereo fit.
pub const STEREO: &str = "fit stereo";
/// Stage: the held-out check (`--report`).
pub const HELD_OUT: &str = "held-out check";
/// Stage: the depth correction's fit (`--depth`).
pub const DEPTH: &str = "depth fit";
/// Stage: starting each worker thread and waiting for its result beyond its own stages
/// (the calibration runs on worker threads so that Ctrl-C is answered at once).
pub const WORKER: &str = "worker threads";

/// Stage: reading and decoding one camera's images.
pub fn read_stage(camera: &str) -> String {
    format!("read {camera}")
}

/// Stage: detecting the board in one camera's images.
pub fn detect_stage(camera: &str) -> String {
    format!("detect {camera}")
}

/// Stage: one camera's own fit (Zhang, LM, outlier rounds; σ and constraint checks apart).
pub fn mono_stage(camera: &str) -> String {
    format!("fit mono {camera}")
}

/// Adds a single-camera fit's stages to `t`: [`mono_stage`], [`SIGMA`], [`FIX_CHECKS`];
/// `call_ms` is the caller's wall time of the whole `calibrate_mono` call.
pub fn add_mono(t: &mut Timings, camera: &str, m: &MonoCalibration, call_ms: f64) {
    add_mono_split(t, camera, &m.timings, Some(call_ms));
}

/// Adds a stereo fit's stages to `t`: each camera's [`mono_stage`] without its σ and
/// constraint checks, [`STEREO`] (the joint fit, and what else the call took besides the
/// two cameras' fits and σ), [`SIGMA`] (all three fits' σ) and [`FIX_CHECKS`]; `call_ms` is
/// the caller's wall time of the whole `calibrate_stereo` call.
pub fn add_stereo(t: &mut Timings, s: &StereoCalibration, call_ms: f64) {
    let own = &s.timings;
    let (depth, color) = (own.get(STAGE_MONO_DEPTH), own.get(STAGE_MONO_COLOR));
    let sigma = own.get(STAGE_SIGMA).unwrap_or(0.0);
    add_mono_split(t, "IR", &s.depth_mono.timings, depth);
    add_mono_split(t, "colour", &s.color_mono.timings, color);
    let joint = call_ms - depth.unwrap_or(0.0) - color.unwrap_or(0.0) - sigma;
    t.add(STEREO, joint);
    t.add(SIGMA, sigma);
}

/// One camera's fit: `total` is the wall time of the whole call where the caller measured it
/// (then the fit stage is what σ and the checks leave of it), else the fit's own stage.
fn add_mono_split(t: &mut Timings, camera: &str, m: &Timings, total: Option<f64>) {
    let sigma = m.get(STAGE_SIGMA).unwrap_or(0.0);
    let checks = m.get(STAGE_FIX_CHECKS);
    let fit = match total {
        Some(total) => total - sigma - checks.unwrap_or(0.0),
        None => m.get(STAGE_FIT).unwrap_or(0.0),
    };
    t.add(&mono_stage(camera), fit);
    t.add(SIGMA, sigma);
    if let Some(c) = checks {
        t.add(FIX_CHECKS, c);
    }
}

/// `report.json`'s `timings_ms`: the stages, the wall time they are part of, and every
/// image's read and detection time.
pub fn report_json(wall_ms: f64, stages: &Timings, images: &[ImageTiming]) -> Value {
    json!({
        "what": "milliseconds of this run: stages in the order they ran, one after another on the calibration's thread (their sum is at most wall_ms, which runs from the start of the command to the writing of report.json); per_image: each image's read-and-decode and detection on its own pool thread (images run in parallel, so these sums can exceed their stage)",
        "wall_ms": wall_ms,
        "stages": stages,
        "per_image": images,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mono_split_inside_a_measured_call_partitions_it() {
        let mut m = Timings::new();
        m.add(STAGE_FIT, 7.0);
        m.add(STAGE_SIGMA, 1.0);
        m.add(STAGE_FIX_CHECKS, 4.0);
        let mut t = Timings::new();
        add_mono_split(&mut t, "IR", &m, Some(12.5));
        assert_eq!(t.get("fit mono IR"), Some(7.5));
        assert_eq!(t.get(SIGMA), Some(1.0));
        assert_eq!(t.get(FIX_CHECKS), Some(4.0));
        assert_eq!(t.total_ms(), 12.5);
        let mut alone = Timings::new();
        add_mono_split(&mut alone, "IR", &m, None);
        assert_eq!(alone.get("fit mono IR"), Some(7.0));
    }
}
