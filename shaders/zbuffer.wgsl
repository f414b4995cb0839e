// H7 z-buffer: the smallest colour-frame z per colour pixel, by atomicMin on the f32 bits
// (positive floats order like their u32 bit patterns). Empty = 0xFFFFFFFF (a NaN), the
// identity of atomicMin. CPU twins: geometry::fusion::zbuffer_index and zbuffer_min.

struct Params {
    // colour width, colour height, number of samples (clear: number of pixels), row stride.
    size: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
// H2's samples: (u, v, z, 1) or all zero.
@group(0) @binding(1) var<storage, read> samples: array<vec4<f32>>;
// Colour-sized, row-major, f32 bit patterns.
@group(0) @binding(2) var<storage, read_write> zbuffer: array<atomic<u32>>;

const EMPTY: u32 = 0xffffffffu;

@compute @workgroup_size(256)
fn clear(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    atomicStore(&zbuffer[i], EMPTY);
}

fn is_nan(x: f32) -> bool {
    let b = bitcast<u32>(x) & 0x7fffffffu;
    return b > 0x7f800000u;
}

@compute @workgroup_size(256)
fn scatter(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    let s = samples[i];
    if s.w != 1.0 {
        return;
    }
    // zbuffer_index: (floor(u + 0.5), floor(v + 0.5)) inside the image, NaN rejected.
    let px = floor(s.x + 0.5);
    let py = floor(s.y + 0.5);
    if is_nan(px) || is_nan(py) {
        return;
    }
    if !(px >= 0.0 && py >= 0.0 && px < f32(params.size.x) && py < f32(params.size.y)) {
        return;
    }
    let index = u32(py) * params.size.x + u32(px);
    atomicMin(&zbuffer[index], bitcast<u32>(s.z));
}
