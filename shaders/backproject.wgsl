// H1 back-projection: depth pixel -> 3D point in the depth camera's frame (metres).
// CPU twin: geometry::fusion::backproject_pixel (+ the finiteness filter of backproject_cloud)
// on depth clipped to the depth range (geometry::fusion::is_sample_in).
// Mirrors it operation by operation: z = value * s; X = x * z; Y = y * z.

struct Params {
    // Number of depth pixels.
    count: u32,
    // Invocations per dispatch row (workgroups along x times the workgroup size).
    row_stride: u32,
    // The depth range's ends (metres) as f32 bits: a sample is within near..=far.
    near_bits: u32,
    far_bits: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Depth values (metres, z or range), row-major.
@group(0) @binding(1) var<storage, read> depth: array<f32>;
// Ray table: 3 floats per pixel (x, y, s) from geometry::fusion::depth_ray_table.
@group(0) @binding(2) var<storage, read> rays: array<f32>;
// One point per depth pixel: (X, Y, Z, 1) for a point, all zero for none.
@group(0) @binding(3) var<storage, read_write> points: array<vec4<f32>>;

const INF_BITS: u32 = 0x7f800000u;

// value > 0 && value < +inf, decided on the bit pattern so NaN can never slip through a
// comparison the shader compiler assumed NaN-free.
fn is_sample(value: f32) -> bool {
    let b = bitcast<u32>(value);
    return b != 0u && b < INF_BITS;
}

fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & INF_BITS) != INF_BITS;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.row_stride + gid.x;
    if i >= params.count {
        return;
    }
    let value = depth[i];
    var out = vec4<f32>(0.0, 0.0, 0.0, 0.0);
    if is_sample(value) && value >= bitcast<f32>(params.near_bits)
        && value <= bitcast<f32>(params.far_bits) {
        let rx = rays[3u * i];
        let ry = rays[3u * i + 1u];
        let s = rays[3u * i + 2u];
        let z = value * s;
        let p = vec3<f32>(rx * z, ry * z, z);
        if is_finite(p.x) && is_finite(p.y) && is_finite(p.z) {
            out = vec4<f32>(p, 1.0);
        }
    }
    points[i] = out;
}
