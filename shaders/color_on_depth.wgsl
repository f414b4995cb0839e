// H6 colour sampled onto the depth grid (bilinear), with the occlusion test against the
// colour-frame depth the colour camera sees (H3's fill). CPU twins:
// geometry::fusion::bilinear_rgb and color_on_depth, mirrored exactly:
//   inside when 0 <= u <= w-1 and 0 <= v <= h-1; x0 = floor(u), fx = u - x0 (same for y);
//   per channel: top = c00 + (c10 - c00)*fx; bottom = c01 + (c11 - c01)*fx;
//                value = top + (bottom - top)*fy; out = floor(value + 0.5);
//   occluded when seen > 0 and z > seen * (1 + tolerance), seen = dense[zbuffer_index(u, v)].

struct Params {
    // colour width, colour height, number of depth pixels, invocations per dispatch row.
    size: vec4<u32>,
    // occlusion tolerance (relative), use the occlusion test (1.0) or not (0.0), unused, unused.
    occlusion: vec4<f32>,
    // Always 0; unknown to the compiler, see keep().
    opaque: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
// H2 samples per depth pixel: (u, v, z, 1) or all zero.
@group(0) @binding(1) var<storage, read> samples: array<vec4<f32>>;
// The colour image as tightly packed RGB bytes (4 bytes per word, little-endian).
@group(0) @binding(2) var<storage, read> color: array<u32>;
// H3 dense colour-frame depth (f32 bits, 0xFFFFFFFF = empty).
@group(0) @binding(3) var<storage, read> dense: array<u32>;
// Per depth pixel: r | g << 8 | b << 16 | 255 << 24 when valid, 0 otherwise.
@group(0) @binding(4) var<storage, read_write> rgba: array<u32>;

fn byte_at(k: u32) -> f32 {
    let word = color[k / 4u];
    return f32((word >> (8u * (k % 4u))) & 0xffu);
}

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

// x, unchanged, but materialised as an f32 so that `a + b * c` is never contracted into a
// fused multiply-add (see project.wgsl).
fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.opaque.x);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    rgba[i] = 0u;
    let s = samples[i];
    if s.w != 1.0 || is_nan(s.x) || is_nan(s.y) {
        return;
    }
    let width = params.size.x;
    let height = params.size.y;
    let wf = f32(width - 1u);
    let hf = f32(height - 1u);
    let u = s.x;
    let v = s.y;
    if !(u >= 0.0 && v >= 0.0 && u <= wf && v <= hf) {
        return;
    }
    let x0f = floor(u);
    let y0f = floor(v);
    let fx = u - x0f;
    let fy = v - y0f;
    let x0 = u32(x0f);
    let y0 = u32(y0f);
    let x1 = min(x0 + 1u, width - 1u);
    let y1 = min(y0 + 1u, height - 1u);
    // Occlusion: the pixel (floor(u + 0.5), floor(v + 0.5)), always inside here.
    if params.occlusion.y == 1.0 {
        let px = floor(u + 0.5);
        let py = floor(v + 0.5);
        if px >= 0.0 && py >= 0.0 && px < f32(width) && py < f32(height) {
            let seen = bitcast<f32>(dense[u32(py) * width + u32(px)]);
            if !is_nan(seen) && seen > 0.0 && s.z > seen * (1.0 + params.occlusion.x) {
                return;
            }
        }
    }
    var out = 0xff000000u;
    for (var k = 0u; k < 3u; k++) {
        let c00 = byte_at(3u * (y0 * width + x0) + k);
        let c10 = byte_at(3u * (y0 * width + x1) + k);
        let c01 = byte_at(3u * (y1 * width + x0) + k);
        let c11 = byte_at(3u * (y1 * width + x1) + k);
        let top = c00 + keep((c10 - c00) * fx);
        let bottom = c01 + keep((c11 - c01) * fx);
        let value = top + keep((bottom - top) * fy);
        out = out | (u32(floor(value + 0.5)) << (8u * k));
    }
    rgba[i] = out;
}
