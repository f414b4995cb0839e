// The preamble of the three decode shaders (decode_stage1/_filter/_edge.wgsl): fusion_gpu::shaders
// puts it before each of them when the crate is compiled. Params is, field for field, the Rust
// struct fusion_gpu::stages::decode::Params.
struct Params {
    // (pixels, row stride of the dispatch, opaque 0, mirror: 1 = scene orientation, 0 = sensor)
    size: vec4<u32>,
    // (bilateral filter on, edge-aware filter on, A* is the minimum amplitude, unused)
    flags: vec4<u32>,
    // (ab_multiplier_per_frq[0..3], ab_multiplier)
    ab: vec4<f32>,
    // (ab_output_multiplier, bilateral tau, bilateral exponent factor, joint_bilateral_max_edge)
    bil: vec4<f32>,
    gauss0: vec4<f32>,
    gauss1: vec4<f32>,
    // (gaussian_kernel[8], individual_ab_threshold, ab_threshold, ab_confidence_slope)
    gauss2: vec4<f32>,
    // (ab_confidence_offset, min_dealias_confidence, max_dealias_confidence, phase_offset)
    conf: vec4<f32>,
    // (unambiguous_dist, edge_ab_avg_min_value, edge_ab_std_dev_threshold, edge_close_delta)
    edge0: vec4<f32>,
    // (edge_far_delta, edge_max_delta, edge_avg_delta, min_depth)
    edge1: vec4<f32>,
    // (max_depth, metres per millimetre of the registration output, unused, unused)
    edge2: vec4<f32>,
    // f64 constants split into f32 parts (see decode_filter.wgsl): 2 pi as (hi, lo, -, -), and
    // 3/2pi, 15/2pi, 2/2pi, 2pi as products (hi, lo, hi's upper 12 bits, hi's lower bits).
    two_pi_add: vec4<f32>,
    mul_t0: vec4<f32>,
    mul_t1: vec4<f32>,
    mul_t2: vec4<f32>,
    mul_two_pi: vec4<f32>,
}

const W: u32 = 512u;
const H: u32 = 424u;
