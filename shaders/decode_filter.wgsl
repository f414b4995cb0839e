// Kinect v2 depth decoding, stage 2 (protocol §9.5, §9.6): the joint bilateral filter of the
// stage-1 phasors, amplitudes and the amplitude gate, phases, the de-aliasing confidence, phase
// unwrapping and depth, one invocation per processing pixel.
// CPU twin: kinect_usb::decoder with DecoderPrecision::Fast (bilateral.rs, stage2.rs,
// unwrap.rs, fastmath.rs). Mirrors it operation by operation:
// * exp, ln and atan2 are fastmath's branch-free f32 functions, constant for constant
//   (WGSL's built-ins differ from them by several ulp);
// * the four places where the CPU computes in f64 and rounds to f32 (phase + 2 pi, the three
//   phase scalings, the three products with 2 pi) use an f32 double-word product / sum: the
//   exact product or sum as a pair of f32 (Dekker, Knuth), plus the f64 constant's low part,
//   rounded once. That equals the CPU's f64-then-f32 result except when the exact value lies
//   within about 2^-48 (relative) of an f32 rounding boundary;
// * every product that feeds a sum, and every step of those error-free transformations, goes
//   through keep() so that no compiler contracts or re-associates it.
// NaN and infinities follow IEEE (tested on bit patterns where a decision depends on them).

// Params, W and H: shaders/include/decode_params.wgsl, put before this file by
// fusion_gpu::shaders.

@group(0) @binding(0) var<uniform> params: Params;
// Stage 1: per processing pixel and frequency (index 3 * pixel + k): (a, b, ua, ub).
@group(0) @binding(1) var<storage, read> s1: array<vec4<f32>>;
// Stage 1: per processing pixel, (n2_0, n2_1, n2_2, 0).
@group(0) @binding(2) var<storage, read> n2: array<vec4<f32>>;
// x and z tables, processing order.
@group(0) @binding(3) var<storage, read> xtab: array<f32>;
@group(0) @binding(4) var<storage, read> ztab: array<f32>;
// Per processing pixel: (depth before the edge-aware filter (mm), amplitude sum, 1 where the
// pixel is valid for the edge filter's neighbour min / max (edge_ok and depth > 0) else 0, 0).
@group(0) @binding(5) var<storage, read_write> pre: array<vec4<f32>>;

fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.size.z);
}

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn infinity() -> f32 {
    return bitcast<f32>(0x7f800000u | params.size.z);
}

// ---- fastmath (kinect_usb::decoder::fastmath), constant for constant ----

// 1.5 * 2^23
const ROUND_MAGIC: f32 = 12582912.0f;
const LOG2_E: f32 = 1.442695f;
const LN2_HI: f32 = 0.6933594f;
const LN2_LO: f32 = -0.00021219444f;
const EXP_P0: f32 = 1.0f;
const EXP_P1: f32 = 1.0f;
const EXP_P2: f32 = 0.4999999f;
const EXP_P3: f32 = 0.1666642f;
const EXP_P4: f32 = 0.041668225f;
const EXP_P5: f32 = 0.008374816f;
const EXP_P6: f32 = 0.0013836846f;
const SQRT_2: f32 = 1.4142135f;
const TAN_PI_8: f32 = 0.41421357f;
const ATAN_P0: f32 = -0.33333316f;
const ATAN_P1: f32 = 0.19998471f;
const ATAN_P2: f32 = -0.14243533f;
const ATAN_P3: f32 = 0.10593813f;
const ATAN_P4: f32 = -0.06078219f;
const PIO4_HI: f32 = 0.7853982f;
const PIO4_LO: f32 = -2.1855694e-8f;
const PIO2_HI: f32 = 1.5707964f;
const PIO2_LO: f32 = -4.371139e-8f;
const PI_HI: f32 = 3.1415927f;
const PI_LO: f32 = -8.742278e-8f;
// 1/9, 1/7, 1/5, 1/3 rounded to f32.
const LN_Q9: f32 = 0.11111111f;
const LN_Q7: f32 = 0.14285715f;
const LN_Q5: f32 = 0.2f;
const LN_Q3: f32 = 0.33333334f;

// fastmath::exp_unclamped: x in [-87, 88] or NaN.
fn exp_unclamped(x: f32) -> f32 {
    let n = keep(keep(x * LOG2_E) + ROUND_MAGIC) - ROUND_MAGIC;
    let r = keep(x - keep(n * LN2_HI)) - keep(n * LN2_LO);
    var p = EXP_P6;
    p = keep(p * r) + EXP_P5;
    p = keep(p * r) + EXP_P4;
    p = keep(p * r) + EXP_P3;
    p = keep(p * r) + EXP_P2;
    p = keep(p * r) + EXP_P1;
    p = keep(p * r) + EXP_P0;
    let e = (i32(n) + 127) << 23u;
    return p * bitcast<f32>(e);
}

// fastmath::exp: clamps to [-87, 88] (NaN passes).
fn exp_clamped(x0: f32) -> f32 {
    var x = x0;
    if x < -87.0f {
        x = -87.0f;
    }
    if x > 88.0f {
        x = 88.0f;
    }
    return exp_unclamped(x);
}

// fastmath::ln: positive normal x (NaN -> NaN).
fn ln(x: f32) -> f32 {
    let bits = bitcast<i32>(x);
    let e0 = ((bits >> 23u) & 0xff) - 127;
    var m = bitcast<f32>((bits & 0x007fffff) | 0x3f800000);
    let big = m > SQRT_2;
    if big {
        m = m * 0.5f;
    }
    let e = f32(e0) + select(0.0f, 1.0f, big);
    let s = keep(m - 1.0f) / keep(m + 1.0f);
    let z = s * s;
    var q = LN_Q9;
    q = keep(q * z) + LN_Q7;
    q = keep(q * z) + LN_Q5;
    q = keep(q * z) + LN_Q3;
    let s2 = 2.0f * s;
    let lnm = s2 + keep(s2 * keep(z * q));
    let r = keep(e * LN2_HI) + keep(lnm + keep(e * LN2_LO));
    return select(r, x, is_nan(x));
}

fn copysign(a: f32, s: f32) -> f32 {
    return bitcast<f32>((bitcast<u32>(a) & 0x7fffffffu) | (bitcast<u32>(s) & 0x80000000u));
}

// fastmath::atan2: finite (y, x) != (0, 0); NaN in either (and (0, 0)) gives NaN.
fn atan2_fast(y: f32, x: f32) -> f32 {
    let ax = abs(x);
    let ay = abs(y);
    let swap = ay > ax;
    let num = select(ay, ax, swap);
    let den = select(ax, ay, swap);
    let big = num > TAN_PI_8 * den;
    let u = select(num, keep(num - den), big) / select(den, keep(num + den), big);
    let z = u * u;
    var p = ATAN_P4;
    p = keep(p * z) + ATAN_P3;
    p = keep(p * z) + ATAN_P2;
    p = keep(p * z) + ATAN_P1;
    p = keep(p * z) + ATAN_P0;
    var a = u + keep(u * keep(z * p));
    if big {
        a = PIO4_HI + keep(a + PIO4_LO);
    }
    if swap {
        a = PIO2_HI - keep(a - PIO2_LO);
    }
    if x < 0.0f {
        a = PI_HI - keep(a - PI_LO);
    }
    return copysign(a, y);
}

// ---- f64 operations of the CPU decoder, emulated in f32 ----

// Dekker's split of x into hi (12 significant bits) + lo, both exact.
fn split(x: f32) -> vec2<f32> {
    let t = keep(x * 4097.0f);
    let hi = keep(t - keep(t - x));
    return vec2<f32>(hi, keep(x - hi));
}

// round_f32(x * C) for the f64 constant C = c.x + c.y (c.x = C rounded to f32, c.y the rest
// rounded to f32, c.z + c.w = c.x split as by split()): x * c.x exactly as p + e (Dekker's
// product), then p + (e + x * c.y) rounded once.
fn mul64(x: f32, c: vec4<f32>) -> f32 {
    if x == 0.0f {
        // +-0 times the positive constant keeps x's sign, as in f64.
        return x;
    }
    let p = keep(x * c.x);
    let xs = split(x);
    let e = keep(keep(keep(keep(keep(xs.x * c.z) - p) + keep(xs.x * c.w)) + keep(xs.y * c.z))
        + keep(xs.y * c.w));
    return p + keep(e + keep(x * c.y));
}

// round_f32(x + C) for the f64 constant C = c.x + c.y: Knuth's two-sum of x + c.x, then the
// rounding error and c.y added, rounded once.
fn add64(x: f32, c: vec4<f32>) -> f32 {
    let s = keep(x + c.x);
    let bb = keep(s - x);
    let err = keep(keep(x - keep(s - bb)) + keep(c.x - bb));
    return s + keep(err + c.y);
}

// ---- bilateral filter (protocol §9.5; bilateral.rs) ----

// The filtered phasor (a, b) of frequency k at processing pixel (x, y), 1 <= x <= 510,
// 1 <= y <= 422, and whether its edge test passed (z = 1.0 or 0.0).
fn bilateral(k: u32, x: u32, y: u32) -> vec3<f32> {
    let i = y * W + x;
    let c = s1[3u * i + k];
    let cn2 = n2[i][k];
    let tau0 = params.bil.y;
    let ce = params.bil.z;
    let centre_passes = cn2 >= tau0;
    var w_acc = 0.0f;
    var sa = 0.0f;
    var sb = 0.0f;
    var d_acc = 0.0f;
    var nan_d = false;
    var nan_w = false;
    // Neighbours in the CPU's order: up-left, up, up-right, left, (centre), right, down-left,
    // down, down-right.
    for (var j = 0u; j < 9u; j++) {
        let dy = j / 3u;
        let dx = j % 3u;
        let g = params.gauss0[j & 3u];
        var gk = g;
        if j >= 4u && j < 8u {
            gk = params.gauss1[j - 4u];
        } else if j == 8u {
            gk = params.gauss2.x;
        }
        if j == 4u {
            let w = params.gauss1.x;
            w_acc = w_acc + w;
            sa = sa + keep(w * c.x);
            sb = sb + keep(w * c.y);
            continue;
        }
        let ni = (y + dy - 1u) * W + (x + dx - 1u);
        let nb = s1[3u * ni + k];
        let nn2 = n2[ni][k];
        // Range distance, symmetric bit for bit: (1 - (ua1 * ua + ub1 * ub)) * 0.5.
        let dist = keep(1.0f - keep(keep(nb.z * c.z) + keep(nb.w * c.w))) * 0.5f;
        var passes: bool;
        var ex: f32;
        if centre_passes {
            passes = nn2 >= tau0;
            ex = exp_unclamped(keep(ce * dist));
        } else {
            // Centre below tau: tau = 0 and exp(-0 * dist) = 1 for a finite dist, NaN else.
            passes = nn2 >= 0.0f;
            ex = select(1.0f, dist, is_nan(dist));
        }
        var weight = 0.0f;
        if passes {
            weight = keep(gk * ex);
            d_acc = d_acc + dist;
            nan_d = nan_d || is_nan(dist);
        }
        nan_w = nan_w || is_nan(weight);
        sa = sa + keep(weight * nb.x);
        sb = sb + keep(weight * nb.y);
        w_acc = w_acc + weight;
    }
    let edge = !nan_d && !is_nan(d_acc) && d_acc < params.bil.w;
    let pos = !nan_w && !is_nan(w_acc) && w_acc > 0.0f;
    var fa = 0.0f;
    var fb = 0.0f;
    if pos {
        fa = sa / w_acc;
        fb = sb / w_acc;
    }
    return vec3<f32>(fa, fb, select(0.0f, 1.0f, edge));
}

// ---- stage 2, unwrapping and depth (protocol §9.6; stage2.rs, unwrap.rs) ----

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.y + gid.x;
    if i >= params.size.x {
        return;
    }
    let y = i / W;
    let x = i % W;
    let filtered = params.flags.x != 0u && y > 0u && y < H - 1u && x > 0u && x < W - 1u;
    var fa: array<f32, 3>;
    var fb: array<f32, 3>;
    var ok = true;
    for (var k = 0u; k < 3u; k++) {
        if filtered {
            let f = bilateral(k, x, y);
            fa[k] = f.x;
            fb[k] = f.y;
            ok = ok && f.z != 0.0f;
        } else {
            let c = s1[3u * i + k];
            fa[k] = c.x;
            fb[k] = c.y;
        }
    }
    // Amplitudes and the gate (step 1-2).
    var al: array<f32, 3>;
    for (var k = 0u; k < 3u; k++) {
        al[k] = sqrt(keep(fa[k] * fa[k]) + keep(fb[k] * fb[k])) * params.ab.w;
    }
    let s = al[0] + al[1] + al[2];
    // fmin(a, b) = b < a ? b : a, as the CPU's.
    let amin01 = select(al[0], al[1], al[1] < al[0]);
    let amin = select(amin01, al[2], al[2] < amin01);
    let amax01 = select(al[0], al[1], al[0] < al[1]);
    let amax = select(amax01, al[2], amax01 < al[2]);
    let astar = select(amax, amin, params.flags.z != 0u);
    let gate = !(amin < params.gauss2.y || s < params.gauss2.z);
    // Phases and confidence (Fast: on every pixel; values outside the gate are discarded).
    var ph: array<f32, 3>;
    for (var k = 0u; k < 3u; k++) {
        var f = atan2_fast(fb[k], fa[k]);
        if is_nan(f) {
            f = 0.0f;
        } else if f < 0.0f {
            f = add64(f, params.two_pi_add);
        }
        ph[k] = f;
    }
    let l = ln(astar);
    let arg = (keep(keep(l * params.gauss2.w) * 0.301030f) + params.conf.x) * 3.321928f;
    let conf = exp_clamped(arg);
    // Unwrapping (step 3).
    let t0 = mul64(ph[0], params.mul_t0);
    let t1 = mul64(ph[1], params.mul_t1);
    let t2 = mul64(ph[2], params.mul_t2);
    let t5 = keep(floor(keep(keep(t1 - t0) * 0.333333f) + 0.5f) * 3.0f) + t0;
    var t3 = t5 - t2;
    let t4 = t3 * 2.0f;
    let pos = t4 >= keep(0.0f - t4);
    t3 = t3 * select(-0.5f, 0.5f, pos);
    t3 = keep(t3 - floor(t3)) * select(-2.0f, 2.0f, pos);
    let at3 = abs(t3);
    let wrap = 0.5f < at3 && at3 < 1.5f;
    var t6 = select(t5, t5 + 15.0f, wrap);
    var t7 = select(t1, t1 + 15.0f, wrap);
    var t8 = keep(keep(floor(keep(keep(t6 - t2) * 0.5f) + 0.5f) * 2.0f) + t2) * 0.5f;
    t6 = t6 * 0.333333f;
    t7 = t7 * 0.066667f;
    let t9 = (t8 + t6) + t7;
    var t10 = t9 * 0.333333f;
    t6 = mul64(t6, params.mul_two_pi);
    t7 = mul64(t7, params.mul_two_pi);
    t8 = mul64(t8, params.mul_two_pi);
    let e8 = keep(t7 * 0.826977f) - keep(t8 * 0.110264f);
    let e6 = keep(t8 * 0.551318f) - keep(t6 * 0.826977f);
    let e7 = keep(t6 * 0.110264f) - keep(t7 * 0.551318f);
    let nu = keep(keep(e8 * e8) + keep(e6 * e6)) + keep(e7 * e7);
    // Multiplied, not selected: a negative t10 becomes -0.0 (protocol §9.9).
    t10 = t10 * keep(select(0.0f, 1.0f, t9 >= 0.0f));
    var cf = conf;
    if cf < params.conf.y {
        cf = params.conf.y;
    }
    if cf > params.conf.z {
        cf = params.conf.z;
    }
    cf = cf * cf;
    var phase = t10 * keep(select(0.0f, 1.0f, cf >= nu));
    if !gate {
        phase = 0.0f;
    }
    // Depth (step 4).
    let phs = select(phase, phase + params.conf.w, phase > 0.0f);
    let zl = ztab[i] * phs;
    let dmax = (phs * params.edge0.x) * 2.0f;
    let xm = (xtab[i] * 90.0f) / (keep(dmax * dmax) * 8192.0f);
    var zf = zl / keep(1.0f - keep(zl * xm));
    if zf < 0.0f {
        zf = 0.0f;
    }
    let d = select(zl, zf, zl > 0.0f && dmax > 0.0f);
    let valid = ok && d > 0.0f;
    pre[i] = vec4<f32>(d, s, select(0.0f, 1.0f, valid), 0.0f);
}
