// H3 nearest-sample fill of the colour grid from the H7 z-buffer, bounded by a disc of
// radius R. CPU twin: geometry::fusion::nearest_fill_pixel, mirrored exactly:
//   pass 1: zmin = smallest non-empty z-buffer value over the disc offsets;
//   pass 2: the first offset (disc order: distance², then dy, then dx) whose value is
//           <= zmin * (1 + depth_jump).
// The offset table is geometry::fusion::disc_offsets(R), uploaded by the host, so both
// sides visit the same pixels in the same order. Empty pixels hold 0xFFFFFFFF (a NaN).

struct Params {
    // colour width, colour height, number of pixels, invocations per dispatch row.
    size: vec4<u32>,
    // number of disc offsets, unused, unused, unused.
    offsets: vec4<u32>,
    // depth_jump (relative), unused, unused, unused.
    jump: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> zbuffer: array<u32>;
@group(0) @binding(2) var<storage, read> offsets: array<vec2<i32>>;
@group(0) @binding(3) var<storage, read_write> dense: array<u32>;

const EMPTY: u32 = 0xffffffffu;

fn is_nan_bits(b: u32) -> bool {
    return (b & 0x7fffffffu) > 0x7f800000u;
}

// The z-buffer bits at (x, y) + offset k, or EMPTY outside the image.
fn tap(x: i32, y: i32, k: u32) -> u32 {
    let o = offsets[k];
    let sx = x + o.x;
    let sy = y + o.y;
    if sx >= 0 && sy >= 0 && sx < i32(params.size.x) && sy < i32(params.size.y) {
        return zbuffer[u32(sy) * params.size.x + u32(sx)];
    }
    return EMPTY;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    let x = i32(i % params.size.x);
    let y = i32(i / params.size.x);
    let n = params.offsets.x;
    // Pass 1: the nearest surface in the disc.
    var zmin_bits = EMPTY;
    for (var k = 0u; k < n; k++) {
        let b = tap(x, y, k);
        if !is_nan_bits(b) && (is_nan_bits(zmin_bits) || !(bitcast<f32>(zmin_bits) <= bitcast<f32>(b))) {
            zmin_bits = b;
        }
    }
    if is_nan_bits(zmin_bits) {
        dense[i] = EMPTY;
        return;
    }
    let limit = bitcast<f32>(zmin_bits) * (1.0 + params.jump.x);
    // Pass 2: the first sample in disc order on that surface.
    var out = EMPTY;
    for (var k = 0u; k < n; k++) {
        let b = tap(x, y, k);
        if !is_nan_bits(b) && bitcast<f32>(b) <= limit {
            out = b;
            break;
        }
    }
    dense[i] = out;
}
