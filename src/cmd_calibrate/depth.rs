//! `kfuse calibrate --depth`'s table: the depth correction `calib::pipeline::depth` fitted
//! (per view, the model order, the terms and what they depend on); its figures are
//! `depth_figures`.

use calib::depth::{DepthFit, MIN_DEPTH_VIEWS, MIN_DISTANCE_SPAN_M};
use geometry::depth_correction::DepthTermKind;

/// Prints the table: per view pixels, distance, RMS before/after, rejections; the terms.
pub(super) fn print_fit(fit: &DepthFit) {
    println!("\ndepth calibration: measured z against the IR board plane");
    println!(
        "  {:<24} {:>7} {:>7} {:>11} {:>11}",
        "view", "pixels", "z (m)", "RMS before", "RMS after"
    );
    for v in &fit.views {
        println!(
            "  {:<24} {:>7} {:>7.3} {:>8.2} mm {:>8.2} mm{}",
            v.name,
            v.pixels,
            v.median_z_m,
            1e3 * v.rms_before_m,
            1e3 * v.rms_after_m,
            v.rejected.as_ref().map(|r| format!("  rejected: {r}")).unwrap_or_default()
        );
    }
    println!("  model order (from the data):");
    for o in &fit.order_steps {
        println!(
            "    {:<16} RMS {:.3} mm, leave-one-view-out {:.3} mm  {}",
            o.terms,
            1e3 * o.rms_m,
            1e3 * o.cv_rms_m,
            if o.kept { "kept" } else { "not kept" }
        );
    }
    let (lo, hi) = fit.distance_range_m;
    println!(
        "  {} views at {lo:.2}–{hi:.2} m; RMS {:.2} mm before, {:.2} mm after",
        fit.views.iter().filter(|v| v.rejected.is_none()).count(),
        1e3 * fit.rms_before_m,
        1e3 * fit.rms_after_m
    );
    for line in fit.correction.describe() {
        println!("  {line}");
    }
    if let Some(sens) = &fit.sensitivity {
        // Beside each term's σ: how far it moves with what the board poses were computed
        // with (a correction belongs with the intrinsics and square it was fitted with).
        println!(
            "  what it depends on (re-fitted with the IR focal length and the square ±{:.0} %):",
            100.0 * sens.step
        );
        println!(
            "    {:<8} {:>12} {:>10} {:>16} {:>18}",
            "term", "value", "1σ", "per +1 % of f", "per +1 % of square"
        );
        for (t, d) in fit.correction.terms.iter().zip(&sens.terms) {
            // The scale in per cent, the other terms in millimetres.
            let (k, unit) =
                if t.kind == DepthTermKind::Scale { (100.0, " %") } else { (1e3, " mm") };
            println!(
                "    {:<8} {:>12} {:>10} {:>16} {:>18}",
                t.kind.name(),
                format!("{:+.3}{unit}", k * t.value),
                format!("{:.3}{unit}", k * t.std),
                format!("{:+.3}{unit}", k * d.per_percent_focal),
                format!("{:+.3}{unit}", k * d.per_percent_square)
            );
        }
        println!(
            "    (the correction holds with the IR intrinsics and square it was fitted with; the rig keeps them together)"
        );
    }
    if hi - lo < 2.0 * MIN_DISTANCE_SPAN_M {
        println!(
            "  note: boards span {:.2} m; views over at least {:.1} m (and ≥ {MIN_DEPTH_VIEWS} of them) pin offset and scale down better",
            hi - lo,
            2.0 * MIN_DISTANCE_SPAN_M
        );
    }
}
