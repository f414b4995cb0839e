// H2 transform + projection into the colour camera (OpenCV distortion applied).
// CPU twins: geometry::fusion::transform_point and project_color_point, mirrored line by line:
// every sum is evaluated left to right, no fused multiply-add, no dot().

struct Projection {
    // Rows of color_from_depth: (r0, r1, r2, t) each.
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    // fx, fy, cx, cy (pixels).
    k: vec4<f32>,
    // skew, k1, k2, p1.
    d0: vec4<f32>,
    // p2, k3, unused, unused.
    d1: vec4<f32>,
    // colour width, colour height, number of points, invocations per dispatch row.
    size: vec4<u32>,
    // Always 0; unknown to the compiler, see keep().
    opaque: vec4<u32>,
}

@group(0) @binding(0) var<uniform> proj: Projection;
// H1's points: (X, Y, Z, 1) or all zero.
@group(0) @binding(1) var<storage, read> points: array<vec4<f32>>;
// Per depth pixel: (u, v, z_color, 1) when the point is in front of the colour camera,
// all zero otherwise. (u, v) may lie outside the colour image.
@group(0) @binding(2) var<storage, read_write> samples: array<vec4<f32>>;

const INF_BITS: u32 = 0x7f800000u;

// z > 0 (NaN fails), decided on the bit pattern: +0 < bits <= +inf.
fn is_positive(z: f32) -> bool {
    let b = bitcast<u32>(z);
    return b != 0u && b <= INF_BITS;
}

// x, unchanged, but materialised as an f32: XOR with a value the compiler cannot know stops
// it from contracting a product and a sum into a fused multiply-add (which would change the
// last bit relative to the CPU twin; WGSL has no `precise`). Every product that feeds a sum
// goes through keep().
fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ proj.opaque.x);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * proj.size.w + gid.x;
    if i >= proj.size.z {
        return;
    }
    let p = points[i];
    var out = vec4<f32>(0.0, 0.0, 0.0, 0.0);
    if p.w == 1.0 {
        // transform_point: ((r0*x + r1*y) + r2*z) + t
        let xc = keep(proj.row0.x * p.x) + keep(proj.row0.y * p.y) + keep(proj.row0.z * p.z) + proj.row0.w;
        let yc = keep(proj.row1.x * p.x) + keep(proj.row1.y * p.y) + keep(proj.row1.z * p.z) + proj.row1.w;
        let zc = keep(proj.row2.x * p.x) + keep(proj.row2.y * p.y) + keep(proj.row2.z * p.z) + proj.row2.w;
        if is_positive(zc) {
            let fx = proj.k.x;
            let fy = proj.k.y;
            let cx = proj.k.z;
            let cy = proj.k.w;
            let skew = proj.d0.x;
            let k1 = proj.d0.y;
            let k2 = proj.d0.z;
            let p1 = proj.d0.w;
            let p2 = proj.d1.x;
            let k3 = proj.d1.y;
            let xn = xc / zc;
            let yn = yc / zc;
            // r2 = xn*xn + yn*yn
            let r2 = keep(xn * xn) + keep(yn * yn);
            // radial = 1 + r2*(k1 + r2*(k2 + r2*k3))
            let radial = 1.0 + keep(r2 * (k1 + keep(r2 * (k2 + keep(r2 * k3)))));
            let xy = xn * yn;
            // xd = xn*radial + 2*p1*xy + p2*(r2 + 2*xn*xn)
            let xd = keep(xn * radial) + keep(2.0 * p1 * xy) + keep(p2 * (r2 + keep(2.0 * xn * xn)));
            // yd = yn*radial + p1*(r2 + 2*yn*yn) + 2*p2*xy
            let yd = keep(yn * radial) + keep(p1 * (r2 + keep(2.0 * yn * yn))) + keep(2.0 * p2 * xy);
            // u = fx*xd + skew*yd + cx; v = fy*yd + cy
            let u = keep(fx * xd) + keep(skew * yd) + cx;
            let v = keep(fy * yd) + cy;
            out = vec4<f32>(u, v, zc, 1.0);
        }
    }
    samples[i] = out;
}
