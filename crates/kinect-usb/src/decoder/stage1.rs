//! Stage 1 (protocol §8, §9.3, §9.4): unpacking the 11-bit codes of a stored row, the
//! phase-step coefficients, and per frequency the complex measurement `(a, b)`, its amplitude and
//! the unit phasor the bilateral filter uses; plus the IR output row (§9.6 step 5), which only
//! needs the stage-1 amplitudes.

use super::lanes::{V, ld, sp, st};
use super::{Ctx, DecoderParams, H, PAD, Plane, Row1, SAT, W};
use crate::params::P0Tables;
use crate::raw::{ROW_BYTES, SUB_IMAGE_BYTES, stored_row_of_processing_row};

/// Largest span of P0 values (per frequency) stored as a table indexed by value rather than
/// as per-pixel planes: 16 384 entries of 32 bytes (512 KB per frequency) still sit in the L2
/// cache, while the per-pixel planes stream 15.6 MB per frame (the vectors' tables span
/// about 3 000 values).
pub(super) const TRIG_TABLE_MAX_SPAN: usize = 16_384;

/// The phase-step coefficients of protocol §9.3, `cos ψ_kj` and `sin(−ψ_kj)`, which depend on the
/// pixel only through its P0 value.
pub(super) enum Trig {
    /// Per processing row, 18 planes: for k = 0..3, `cos ψ_k0..2` then `sin(−ψ_k0..2)`.
    Planes(Vec<[Plane; 18]>),
    /// Per frequency k, entry `P − min P` = `[cos ψ_k0..2, 0, sin(−ψ_k0..2), 0]`; per processing
    /// row and frequency, each pixel's entry.
    Table { table: [Vec<[f32; 8]>; 3], index: Vec<[[u16; W]; 3]> },
}

/// The phase-step coefficients of protocol §9.3 for a pixel whose P0 value is `p0`:
/// `[cos ψ_0, cos ψ_1, cos ψ_2, 0, sin(−ψ_0), sin(−ψ_1), sin(−ψ_2), 0]` with
/// `ψ_j = θ + phase_in_rad[j]`, `θ = −P0 · 0.000031 · π` (f64, rounded to f32), in the f32
/// precision both CPU decoders use. Public so that other decoders (the GPU one in `fusion-gpu`)
/// upload exactly the CPU's coefficients.
pub fn phase_step_coefficients(params: &DecoderParams, p0: u16) -> [f32; 8] {
    let theta = (-(p0 as f64) * 0.000031 * std::f64::consts::PI) as f32;
    let mut e = [0f32; 8];
    for j in 0..3 {
        let psi = theta + params.phase_in_rad[j];
        e[j] = psi.cos();
        e[4 + j] = (-psi).sin();
    }
    e
}

impl Trig {
    /// A table if every frequency's P0 values span less than `max_span` values, else planes.
    #[allow(clippy::needless_range_loop)] // x indexes the P0 table and 18 planes.
    pub(super) fn new(params: &DecoderParams, p0: &P0Tables, max_span: usize) -> Self {
        let coefficients = |p: u16| phase_step_coefficients(params, p);
        let range = |t: &[u16]| {
            (t.iter().copied().min().unwrap_or(0), t.iter().copied().max().unwrap_or(0))
        };
        let spans = p0.tables.each_ref().map(|t| range(t));
        // P0 row 423 − y is processing row y (protocol §9.3).
        let p0_at = |k: usize, y: usize, x: usize| p0.tables[k][(H - 1 - y) * W + x];
        if spans.iter().all(|&(lo, hi)| ((hi - lo) as usize) < max_span) {
            let base = spans.map(|(lo, _)| lo);
            let table = [0, 1, 2].map(|k| (spans[k].0..=spans[k].1).map(coefficients).collect());
            let index = (0..H)
                .map(|y| [0, 1, 2].map(|k| std::array::from_fn(|x| p0_at(k, y, x) - base[k])))
                .collect();
            Trig::Table { table, index }
        } else {
            let mut planes = vec![[[0f32; W]; 18]; H];
            for (y, pl) in planes.iter_mut().enumerate() {
                for x in 0..W {
                    for k in 0..3 {
                        let e = coefficients(p0_at(k, y, x));
                        for j in 0..3 {
                            pl[6 * k + j][x] = e[j];
                            pl[6 * k + 3 + j][x] = e[4 + j];
                        }
                    }
                }
            }
            Trig::Planes(planes)
        }
    }

    /// Lanes x..x + 4 of `[cos ψ_k0, cos ψ_k1, cos ψ_k2, sin(−ψ_k0), sin(−ψ_k1), sin(−ψ_k2)]` of
    /// processing row y.
    #[inline(always)]
    pub(super) fn lanes(&self, y: usize, k: usize, x: usize) -> [V; 6] {
        match self {
            Trig::Planes(planes) => {
                let pl = &planes[y];
                [0, 1, 2, 3, 4, 5].map(|j| ld(&pl[6 * k + j], x))
            }
            Trig::Table { table, index } => {
                let (t, ix) = (&table[k], &index[y][k]);
                let entries = [0, 1, 2, 3].map(|l| &t[ix[x + l] as usize]);
                let [c0, c1, c2, _] = V::transpose(entries.map(|e| ld(e, 0)));
                let [s0, s1, s2, _] = V::transpose(entries.map(|e| ld(e, 4)));
                [c0, c1, c2, s0, s1, s2]
            }
        }
    }
}

/// Unpacks the 512 11-bit codes of one 704-byte stored row through the LUT into image-column
/// order (protocol §8). Slots `8g .. 8g + 8` occupy the 11 bytes from `11g`; slot `q` holds column
/// `4·(q mod 128) + q div 128`. Columns 0 and 511 are never read by the decoder: 0.
#[inline(always)]
pub(super) fn unpack_row(row: &[u8], lut: &[f32; 2048], out: &mut Plane) {
    for g in 0..64 {
        let o = 11 * g;
        let (mut lo, mut hi) = ([0u8; 8], [0u8; 8]);
        lo.copy_from_slice(&row[o..o + 8]);
        hi.copy_from_slice(&row[o + 3..o + 11]);
        let (lo, hi) = (u64::from_le_bytes(lo), u64::from_le_bytes(hi));
        // Code i of the group starts at bit 11·i; codes 5..7 are read from the second load,
        // which starts 24 bits later.
        let codes = [lo, lo >> 11, lo >> 22, lo >> 33, lo >> 44, hi >> 31, hi >> 42, hi >> 53];
        let base = 32 * (g % 16) + g / 16;
        for (i, code) in codes.into_iter().enumerate() {
            out[base + 4 * i] = lut[(code & 0x7ff) as usize];
        }
    }
    out[0] = 0.0;
    out[W - 1] = 0.0;
}

/// Stage 1 (protocol §9.4) of processing row `y`, plus the bilateral per-pixel terms if `unit`.
#[inline(always)]
pub(super) fn stage1_row(c: &Ctx, y: usize, m: &mut [Plane; 9], out: &mut Row1, unit: bool) {
    let stored = stored_row_of_processing_row(y);
    for (s, ms) in m.iter_mut().enumerate() {
        let off = s * SUB_IMAGE_BYTES + stored * ROW_BYTES;
        unpack_row(&c.raw[off..off + ROW_BYTES], &c.t.lut, ms);
    }
    let z = &c.t.z[y];
    let p = c.p;
    let (zero, abm, sat) = (sp(0.0), sp(p.ab_multiplier), sp(SAT));
    for k in 0..3 {
        let (m0, m1, m2) = (&m[3 * k], &m[3 * k + 1], &m[3 * k + 2]);
        let mk = sp(p.ab_multiplier_per_frq[k]);
        let Row1 { a: oa, b: ob, amp: oamp, ua, ub, n2 } = out;
        let (oa, ob, oamp, ua, ub, n2) =
            (&mut oa[k], &mut ob[k], &mut oamp[k], &mut ua[k], &mut ub[k], &mut n2[k]);
        for x in (0..W / 4).map(|g| 4 * g) {
            let (v0, v1, v2) = (ld(m0, x), ld(m1, x), ld(m2, x));
            let [c0, c1, c2, s0, s1, s2] = c.t.trig.lanes(y, k, x);
            let a = (c0 * v0 + c1 * v1 + c2 * v2) * mk;
            let b = (s0 * v0 + s1 * v1 + s2 * v2) * mk;
            let amp = (a * a + b * b).sqrt() * abm;
            let is_sat = v0.simd_eq(sat) | v1.simd_eq(sat) | v2.simd_eq(sat);
            // ztable ≤ 0: invalid pixel (0, 0, 0); else saturated: (0, 0, 65535).
            let invalid = ld(z, x).simd_le(zero);
            let zero_ab = invalid | is_sat;
            let (a, b) = (zero_ab.select(zero, a), zero_ab.select(zero, b));
            st(oa, x + PAD, a);
            st(ob, x + PAD, b);
            st(oamp, x, invalid.select(zero, is_sat.select(sp(65535.0), amp)));
            if unit {
                let n = a * a + b * b;
                let g = sp(1.0) / n.sqrt();
                let g = g.is_nan().select(sp(f32::INFINITY), g);
                st(ua, x + PAD, a * g);
                st(ub, x + PAD, b * g);
                st(n2, x + PAD, n);
            }
        }
    }
}

/// IR output (protocol §9.6 step 5) of one row from the stage-1 amplitudes.
#[inline(always)]
pub(super) fn ir_row(r: &Row1, p: &DecoderParams, out: &mut [f32]) {
    let (third, mult, max) = (sp(0.3333333), sp(p.ab_output_multiplier), sp(65535.0));
    for x in (0..W / 4).map(|g| 4 * g) {
        let v = (ld(&r.amp[0], x) + ld(&r.amp[1], x) + ld(&r.amp[2], x)) * third * mult;
        st(out, x, v.simd_gt(max).select(max, v));
    }
}

#[cfg(test)]
mod tests {
    use super::{DecoderParams, H, Trig, W};
    use crate::params::P0Tables;
    use rand::{Rng, SeedableRng};

    /// The value-indexed table and the per-pixel planes must give the same coefficient lanes,
    /// bit for bit (zero tolerance: both are the same f32 values, stored differently), for
    /// random P0 tables whose values span 3 000 (like the vectors'), at every pixel.
    #[test]
    fn trig_table_equals_trig_planes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let p0 = P0Tables {
            tables: [11_000u16, 2_000, 17_000]
                .map(|lo| (0..W * H).map(|_| rng.random_range(lo..lo + 3_000)).collect()),
        };
        let params = DecoderParams::default();
        let (table, planes) = (Trig::new(&params, &p0, 16_384), Trig::new(&params, &p0, 0));
        assert!(matches!(table, Trig::Table { .. }) && matches!(planes, Trig::Planes(_)));
        for y in 0..H {
            for k in 0..3 {
                for x in (0..W).step_by(4) {
                    let (t, p) = (table.lanes(y, k, x), planes.lanes(y, k, x));
                    for j in 0..6 {
                        let (t, p) = (t[j].to_array(), p[j].to_array());
                        assert!(
                            t.iter().zip(&p).all(|(a, b)| a.to_bits() == b.to_bits()),
                            "y {y} k {k} x {x} j {j}: {t:?} vs {p:?}"
                        );
                    }
                }
            }
        }
    }
}
