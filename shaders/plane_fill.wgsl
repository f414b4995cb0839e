// H8 hole filling from a fitted plane n·X = d (colour camera frame; the RANSAC fit itself
// runs on the CPU: geometry::fusion::fit_plane_ransac). Every hole pixel takes the plane's z
// along its undistorted ray (x, y, 1) from the colour camera's ray table; other pixels keep
// the H3 value. CPU twin: geometry::fusion::plane_depth_pixel:
//   den = n0*x + n1*y + n2; z = d / den; used only when 0 < z < +inf.

struct Params {
    // colour width, colour height, number of pixels, invocations per dispatch row.
    size: vec4<u32>,
    // n0, n1, n2, d.
    plane: vec4<f32>,
    // Always 0; unknown to the compiler, see keep().
    opaque: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> dense: array<u32>;
@group(0) @binding(2) var<storage, read> holes: array<u32>;
// Colour camera ray table: (x, y) per pixel, NaN where the lens folds.
@group(0) @binding(3) var<storage, read> rays: array<vec2<f32>>;
@group(0) @binding(4) var<storage, read_write> filled: array<u32>;

// x, unchanged, but materialised as an f32: XOR with a value the compiler cannot know
// stops it from contracting `a * b + c` into a fused multiply-add (lavapipe does that here,
// which changes the last bit relative to the CPU twin).
fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.opaque.x);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    var out = dense[i];
    if holes[i] == 1u {
        let ray = rays[i];
        let den = keep(keep(params.plane.x * ray.x) + keep(params.plane.y * ray.y)) + params.plane.z;
        let z = params.plane.w / den;
        let b = bitcast<u32>(z);
        // 0 < z < +inf on the bits (NaN, negatives and zero fail).
        if b != 0u && b < 0x7f800000u {
            out = b;
        }
    }
    filled[i] = out;
}
