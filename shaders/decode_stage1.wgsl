// Kinect v2 depth decoding, stage 1 (protocol §8, §9.3, §9.4, §9.6 step 5): one invocation per
// pixel of the 512 x 424 frame, in *processing* coordinates (row y = 423 - output row).
// CPU twin: kinect_usb::decoder (stage1.rs: unpack_row, stage1_row, ir_row). Mirrors it
// operation by operation (same f32 order; every product that feeds a sum goes through keep()
// so that no compiler contracts it into a fused multiply-add).
//
// In:  the raw frame (10 sub-images of 424 stored rows of 704 bytes; 9 are read), the 11-bit
//      LUT, the phase-step coefficient table (by P0 value) and each pixel's entries in it, the
//      z table.
// Out: per pixel and frequency k, (a, b, a*g, b*g) with g = 1/sqrt(a^2 + b^2) (NaN -> +inf),
//      the three n^2 = a^2 + b^2, and the upright IR image.

// Params, W and H: shaders/include/decode_params.wgsl, put before this file by
// fusion_gpu::shaders.
const ROW_BYTES: u32 = 704u;
const SUB_IMAGE_BYTES: u32 = 298496u; // 704 * 424
// LUT value of a saturated code (i16 32767).
const SAT: f32 = 32767.0f;

@group(0) @binding(0) var<uniform> params: Params;

// The output column of processing column x: mirrored (W - 1 - x) in the scene orientation,
// kfuse's rule (size.w = 1; kinect_usb::orientation), as is in the sensor's (size.w = 0).
fn out_column(x: u32) -> u32 {
    return select(x, W - 1u - x, params.size.w != 0u);
}
// The raw frame as little-endian 32-bit words (2 984 960 bytes).
@group(0) @binding(1) var<storage, read> raw: array<u32>;
// The 2048-entry companding LUT (protocol §8) as f32.
@group(0) @binding(2) var<storage, read> lut: array<f32>;
// Phase-step coefficients by P0 value (minus the frequency's smallest): two entries per value,
// (cos psi_0, cos psi_1, cos psi_2, 0) and (sin -psi_0, sin -psi_1, sin -psi_2, 0); the three
// frequencies' tables one after the other.
@group(0) @binding(3) var<storage, read> trig: array<vec4<f32>>;
// Per processing pixel: the entry index (in vec4 pairs) of each frequency in `trig`.
@group(0) @binding(4) var<storage, read> trig_index: array<vec4<u32>>;
// z table, processing order.
@group(0) @binding(5) var<storage, read> ztab: array<f32>;
// Per processing pixel and frequency (index 3 * pixel + k): (a, b, ua, ub).
@group(0) @binding(6) var<storage, read_write> s1: array<vec4<f32>>;
// Per processing pixel: (n2_0, n2_1, n2_2, 0).
@group(0) @binding(7) var<storage, read_write> n2: array<vec4<f32>>;
// Upright IR image.
@group(0) @binding(8) var<storage, read_write> ir: array<f32>;

// x unchanged, but opaque to the compiler (params.size.z is always 0): a product passed through
// keep() cannot be contracted into a fused multiply-add with the sum it feeds.
fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.size.z);
}

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

// Stored row of processing row y (kinect_usb::raw::stored_row_of_processing_row).
fn stored_row(y: u32) -> u32 {
    if y < 212u {
        return y + 212u;
    }
    return 423u - y;
}

// LUT value of image column x of sub-image s in stored row `stored`: slot
// q = x / 4 + 128 * (x mod 4) holds bits 11q .. 11q + 10 of the row (little-endian).
fn measurement(s: u32, stored: u32, x: u32) -> f32 {
    let q = (x >> 2u) + 128u * (x & 3u);
    let bit = (s * SUB_IMAGE_BYTES + stored * ROW_BYTES) * 8u + 11u * q;
    let w = bit >> 5u;
    let sh = bit & 31u;
    var v = raw[w] >> sh;
    if sh > 21u {
        v = v | (raw[w + 1u] << (32u - sh));
    }
    return lut[v & 0x7ffu];
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.y + gid.x;
    if i >= params.size.x {
        return;
    }
    let y = i / W;
    let x = i % W;
    let stored = stored_row(y);
    // Columns 0 and 511 are never decoded: 0 (as unpack_row).
    let edge_col = x == 0u || x == W - 1u;
    var m: array<f32, 9>;
    for (var s = 0u; s < 9u; s++) {
        m[s] = select(measurement(s, stored, x), 0.0f, edge_col);
    }
    let zt = ztab[i];
    let invalid = zt <= 0.0f;
    let idx = trig_index[i];
    let abm = params.ab.w;
    var amp: array<f32, 3>;
    var nn = vec4<f32>(0.0f, 0.0f, 0.0f, 0.0f);
    for (var k = 0u; k < 3u; k++) {
        let v0 = m[3u * k];
        let v1 = m[3u * k + 1u];
        let v2 = m[3u * k + 2u];
        let c = trig[2u * idx[k]];
        let sn = trig[2u * idx[k] + 1u];
        let mk = params.ab[k];
        var a = (keep(keep(c.x * v0) + keep(c.y * v1)) + keep(c.z * v2)) * mk;
        var b = (keep(keep(sn.x * v0) + keep(sn.y * v1)) + keep(sn.z * v2)) * mk;
        let am = sqrt(keep(a * a) + keep(b * b)) * abm;
        let is_sat = v0 == SAT || v1 == SAT || v2 == SAT;
        if invalid || is_sat {
            a = 0.0f;
            b = 0.0f;
        }
        amp[k] = select(select(am, 65535.0f, is_sat), 0.0f, invalid);
        let n = keep(a * a) + keep(b * b);
        var g = 1.0f / sqrt(n);
        if is_nan(g) {
            g = bitcast<f32>(0x7f800000u | params.size.z);
        }
        s1[3u * i + k] = vec4<f32>(a, b, a * g, b * g);
        nn[k] = n;
    }
    n2[i] = nn;
    let v = (amp[0] + amp[1] + amp[2]) * 0.3333333f * params.bil.x;
    ir[(H - 1u - y) * W + out_column(x)] = select(v, 65535.0f, v > 65535.0f);
}
