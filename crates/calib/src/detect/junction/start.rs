//! The junction fit's start: mean, contrast and blur estimated from the window (see
//! [`start_estimate`]). A module of its own for a measured reason: in `junction.rs` it changed
//! the code LLVM generated for the fit's kernel (register allocation of the product loop), and
//! the kernel ran ~60 % more instructions per pixel (callgrind, robot-arm corpus set: 70 → 114
//! per pixel); here both kernel clones compile to the same instructions as without it.

use nalgebra::Vector2;

use super::{FIT_MIN_PIXELS, SATURATED, START_SIGMA_RANGE};

/// Start of [`fit_junction`]'s mean, contrast and blur `[m, a, σ]`, from one pass over the
/// unsaturated pixels within `r` of `start` (edge angles `theta`): a linear least-squares fit
/// of the sharp model `m + a·s₁s₂ + bᵤ·u + bᵥ·v` (sᵢ = ±1 the side of edge line i, u, v the
/// offsets from `start`). Blur lowers that fit's contrast and raises its residual, both in
/// proportion to σ times the length L of the edges in the window, and the two together give σ
/// and the blurred model's contrast. (Its gradient is not used: on the IR bench image, where
/// glare clips the white squares, starting from it cost more iterations than starting at 0.)
/// `None` for too few pixels or no contrast.
pub(super) fn start_estimate(
    pix: &[(f64, f64, f64)],
    start: Vector2<f64>,
    theta: [f64; 2],
    r: f64,
) -> Option<[f64; 3]> {
    use nalgebra::{Matrix4, Vector4};
    let (s1, c1, s2, c2) = (theta[0].sin(), theta[0].cos(), theta[1].sin(), theta[1].cos());
    // Sums of the normal equations of rows [1, s, u, v] (s² = 1) and values b, as scalars:
    // a nalgebra 4×4 outer product per pixel cost a third of a kernel evaluation per fit.
    let [mut n, mut ss, mut su, mut sv, mut ssu, mut ssv, mut suu, mut suv, mut svv] = [0.0; 9];
    let [mut sb, mut ssb, mut sub, mut svb, mut sbb] = [0.0; 5];
    // Edge length: pixels within half a pixel of either line.
    let mut edge = 0.0;
    for &(x, y, b) in pix {
        let (u, v) = (x - start.x, y - start.y);
        if u * u + v * v > r * r || b >= SATURATED {
            continue;
        }
        let (d1, d2) = (c1 * v - s1 * u, c2 * v - s2 * u);
        let s = if (d1 >= 0.0) == (d2 >= 0.0) { 1.0 } else { -1.0 };
        edge += f64::from(u8::from(d1.abs() < 0.5) + u8::from(d2.abs() < 0.5));
        n += 1.0;
        ss += s;
        su += u;
        sv += v;
        ssu += s * u;
        ssv += s * v;
        suu += u * u;
        suv += u * v;
        svv += v * v;
        sb += b;
        ssb += s * b;
        sub += u * b;
        svb += v * b;
        sbb += b * b;
    }
    #[rustfmt::skip]
    let ata = Matrix4::new(
        n, ss, su, sv,
        ss, n, ssu, ssv,
        su, ssu, suu, suv,
        sv, ssv, suv, svv,
    );
    let (atb, btb) = (Vector4::new(sb, ssb, sub, svb), sbb);
    if n < FIT_MIN_PIXELS as f64 || edge < 1.0 {
        return None;
    }
    let sol = ata.cholesky()?.solve(&atb);
    let (m, a_sharp) = (sol[0], sol[1]);
    if a_sharp.abs() < 1e-6 {
        return None;
    }
    let residual = (btb - sol.dot(&atb)).max(0.0);
    // Per unit length of an edge blurred by σ, the sharp model loses ∫(1 − |erf(d/√2σ)|) dd =
    // C1·σ of its contrast and leaves ∫(erf(d/√2σ) − sign d)² dd = C2·σ of squared residual
    // (per unit contrast²). With k = σL/n: a_sharp = a(1 − C1·k), residual/n = a²(C2·k −
    // C1²k²), so ρ = residual/(n·a_sharp²) solves ρ(1 − C1·k)² = C2·k − C1²k², a quadratic
    // C1²(ρ + 1)k² − (2C1ρ + C2)k + ρ = 0 whose smaller root is k.
    const C1: f64 = 1.595_769_121_605_731; // 2√2/√π
    const C2: f64 = 0.934_779_909_020_436_3; // 2√2(2 − √2)/√π
    let rho = residual / (n * a_sharp * a_sharp);
    let (qa, qb) = (C1 * C1 * (rho + 1.0), 2.0 * C1 * rho + C2);
    let k = (qb - (qb * qb - 4.0 * qa * rho).max(0.0).sqrt()) / (2.0 * qa);
    let sigma = (k * n / edge).clamp(START_SIGMA_RANGE.0, START_SIGMA_RANGE.1);
    // The contrast lost to blur, kept below 70 % (a blur of about a third of the window's
    // radius: C1·k ≈ 2σ/r for a junction at the window's centre).
    let a = a_sharp / (1.0 - C1 * sigma * edge / n).max(0.3);
    Some([m, a, sigma])
}
