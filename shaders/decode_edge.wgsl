// Kinect v2 depth decoding, pass 2 (protocol §9.7, §9.8): the edge-aware filter, which rejects
// depth at flying-pixel edges and clamps to [min_depth, max_depth], and the flip of processing
// row y to upright output row 423 - y; one invocation per pixel. Also writes the depth in
// metres (depth * metres-per-millimetre, one f32 product) for the registration stages.
// CPU twin: kinect_usb::decoder edge.rs (output_row), operation by operation.

// Params, W and H: shaders/include/decode_params.wgsl, put before this file by
// fusion_gpu::shaders.

@group(0) @binding(0) var<uniform> params: Params;

// The output column of processing column x: mirrored (W - 1 - x) in the scene orientation,
// kfuse's rule (size.w = 1; kinect_usb::orientation), as is in the sensor's (size.w = 0).
fn out_column(x: u32) -> u32 {
    return select(x, W - 1u - x, params.size.w != 0u);
}
// Stage 2: per processing pixel (depth mm, amplitude sum, valid for the neighbour min/max, 0).
@group(0) @binding(1) var<storage, read> pre: array<vec4<f32>>;
// Upright depth, millimetres (the decoder's output).
@group(0) @binding(2) var<storage, read_write> depth_mm: array<f32>;
// Upright depth, metres (what the registration stages read).
@group(0) @binding(3) var<storage, read_write> depth_m: array<f32>;

fn keep(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ params.size.z);
}

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn in_range(v: f32) -> bool {
    return v >= params.edge1.w && v <= params.edge2.x;
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.y + gid.x;
    if i >= params.size.x {
        return;
    }
    let y = i / W;
    let x = i % W;
    let c = pre[i];
    let dc = c.x;
    var result = dc;
    if params.flags.y != 0u {
        if y == 0u || y == H - 1u || x == 0u || x == W - 1u {
            result = select(0.0f, dc, in_range(dc));
        } else {
            let sc = c.y;
            var sum = sc;
            var sq = keep(sc * sc);
            var lo = dc;
            var hi = dc;
            // Neighbours in raster order; invalid ones (edge_ok false or depth <= 0) take no
            // part in the min / max (the CPU's +-inf planes).
            for (var j = 0u; j < 9u; j++) {
                if j == 4u {
                    continue;
                }
                let n = pre[(y + j / 3u - 1u) * W + (x + j % 3u - 1u)];
                sum = sum + n.y;
                sq = sq + keep(n.y * n.y);
                if n.z != 0.0f {
                    // fmin(lo, d) = d < lo ? d : lo; fmax(hi, d) = hi < d ? d : hi.
                    lo = select(lo, n.x, n.x < lo);
                    hi = select(hi, n.x, hi < n.x);
                }
            }
            let avg_amp = sum / 9.0f;
            let floor_amp = select(avg_amp, params.edge0.y, avg_amp < params.edge0.y);
            let sigma = sqrt(keep(sq * 9.0f) - keep(sum * sum)) / 9.0f / floor_amp;
            let dlo = abs(dc - lo);
            let dhi = abs(dc - hi);
            let avg = (dlo + dhi) * 0.5f;
            let mx = select(dlo, dhi, dlo < dhi);
            let reject = dc > 0.0f && !is_nan(sigma) && sigma >= params.edge0.z
                && dlo > params.edge0.w && dhi > params.edge1.x && mx > params.edge1.y
                && avg > params.edge1.z;
            let keep_it = in_range(dc) && c.z != 0.0f && !reject;
            result = select(0.0f, dc, keep_it);
        }
    }
    let o = (H - 1u - y) * W + out_column(x);
    depth_mm[o] = result;
    depth_m[o] = result * params.edge2.y;
}
