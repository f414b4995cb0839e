//! Forward model (protocol §14.2): a scene's depth (mm) and IR amplitude → the raw 11-bit frame the
//! decoder turns back into that scene (within quantisation). Used by the simulated device.

use crate::decoder::DecoderParams;
use crate::params::{P0Tables, XzTables};
use crate::raw::{
    HEIGHT, PIXELS, RAW_FRAME_BYTES, ROW_BYTES, SUB_IMAGE_BYTES, WIDTH, encode, lut,
    slot_of_column, stored_row_of_output_row, write_code,
};

/// Wrap periods of the three frequencies' phases in units of the common wrap counter.
const WRAP_PERIODS: [f64; 3] = [3.0, 15.0, 2.0];

/// Builds the raw frame for an upright scene (`depth_mm`, `ir`, 512 × 424 each). Pixels that
/// cannot be represented (depth ≤ 0 or NaN, `ztable ≤ 0`) get all-zero codes and decode to 0.
/// Sub-image 9 is left zero (the decoder ignores it).
pub fn forward_frame(
    depth_mm: &[f32],
    ir: &[f32],
    xz: &XzTables,
    p0: &P0Tables,
    p: &DecoderParams,
) -> Vec<u8> {
    let mut out = vec![0u8; RAW_FRAME_BYTES];
    forward_frame_into(depth_mm, ir, xz, p0, p, &mut out);
    out
}

/// As [`forward_frame`], writing into `out` (2 984 960 bytes).
pub fn forward_frame_into(
    depth_mm: &[f32],
    ir: &[f32],
    xz: &XzTables,
    p0: &P0Tables,
    p: &DecoderParams,
    out: &mut [u8],
) {
    assert_eq!(out.len(), RAW_FRAME_BYTES, "raw frame buffer");
    assert!(depth_mm.len() == PIXELS && ir.len() == PIXELS, "scene must be 512 x 424");
    out.fill(0);
    let table = lut();
    let two_pi = 2.0 * std::f64::consts::PI;
    let ud = p.unambiguous_dist as f64;
    let kappa = (0.5f64 + 0.333333 + 0.066667) * 0.333333;
    for r in 0..HEIGHT {
        let y = HEIGHT - 1 - r;
        let stored = stored_row_of_output_row(r);
        for c in 0..WIDTH {
            let z = depth_mm[r * WIDTH + c] as f64;
            let i = ir[r * WIDTH + c] as f64;
            let zt = xz.z[y * WIDTH + c] as f64;
            let xt = xz.x[y * WIDTH + c] as f64;
            if !(z > 0.0) || !(zt > 0.0) || !(i > 0.0) {
                continue;
            }
            let beta = xt * 90.0 / (8192.0 * 4.0 * ud * ud);
            let disc = z * z - 4.0 * zt * zt * beta * z;
            if disc < 0.0 {
                continue;
            }
            let ph = (z + disc.sqrt()) / (2.0 * zt);
            let t = ph / kappa;
            let slot = slot_of_column(c);
            for (k, period) in WRAP_PERIODS.iter().enumerate() {
                let frac = (t / period).fract();
                let phi = two_pi * frac;
                let amp = i / (16.0 * p.ab_multiplier_per_frq[k] as f64);
                let pv = p0.tables[k][r * WIDTH + c];
                let theta = (-(pv as f64) * 0.000031 * std::f64::consts::PI) as f32;
                for j in 0..3 {
                    let psi = (theta + p.phase_in_rad[j]) as f64;
                    let m = amp * (phi + psi).cos();
                    let code = encode(m, &table);
                    let s = 3 * k + j;
                    let row = &mut out[s * SUB_IMAGE_BYTES + stored * ROW_BYTES..][..ROW_BYTES];
                    write_code(row, slot, code);
                }
            }
        }
    }
}
