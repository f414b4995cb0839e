//! The WGSL sources of every stage, compiled into the crate from the workspace's `shaders/`.
//! The three decode shaders share one preamble, `shaders/include/decode_params.wgsl` (their
//! `Params` and the frame's size), put before each of them here.

/// H1 back-projection (`main`).
pub const BACKPROJECT: &str = include_str!("../../../shaders/backproject.wgsl");
/// H2 transform + projection into the colour camera (`main`).
pub const PROJECT: &str = include_str!("../../../shaders/project.wgsl");
/// H7 z-buffer (`clear`, `scatter`).
pub const ZBUFFER: &str = include_str!("../../../shaders/zbuffer.wgsl");

/// H3 nearest-sample fill of the colour grid (`main`).
pub const NEAREST_FILL: &str = include_str!("../../../shaders/nearest_fill.wgsl");
/// H8 disocclusion hole mask (`clear_extents`, `coverage`, `mask`).
pub const HOLE_MASK: &str = include_str!("../../../shaders/hole_mask.wgsl");
/// H8 hole filling from a fitted plane (`main`).
pub const PLANE_FILL: &str = include_str!("../../../shaders/plane_fill.wgsl");
/// H6 colour sampled onto the depth grid, bilinear (`main`).
pub const COLOR_ON_DEPTH: &str = include_str!("../../../shaders/color_on_depth.wgsl");

/// Kinect v2 depth decoding, stage 1: unpacking, phasors, IR (`main`).
pub const DECODE_STAGE1: &str = concat!(
    include_str!("../../../shaders/include/decode_params.wgsl"),
    include_str!("../../../shaders/decode_stage1.wgsl")
);
/// Kinect v2 depth decoding: bilateral filter, stage 2, unwrapping, depth (`main`).
pub const DECODE_FILTER: &str = concat!(
    include_str!("../../../shaders/include/decode_params.wgsl"),
    include_str!("../../../shaders/decode_filter.wgsl")
);
/// Kinect v2 depth decoding: edge-aware filter and flip to upright rows (`main`).
pub const DECODE_EDGE: &str = concat!(
    include_str!("../../../shaders/include/decode_params.wgsl"),
    include_str!("../../../shaders/decode_edge.wgsl")
);

/// Every shader as `(file name, source)`, for validation and tooling.
pub const ALL: &[(&str, &str)] = &[
    ("backproject.wgsl", BACKPROJECT),
    ("color_on_depth.wgsl", COLOR_ON_DEPTH),
    ("decode_edge.wgsl", DECODE_EDGE),
    ("decode_filter.wgsl", DECODE_FILTER),
    ("decode_stage1.wgsl", DECODE_STAGE1),
    ("hole_mask.wgsl", HOLE_MASK),
    ("nearest_fill.wgsl", NEAREST_FILL),
    ("plane_fill.wgsl", PLANE_FILL),
    ("project.wgsl", PROJECT),
    ("zbuffer.wgsl", ZBUFFER),
];
