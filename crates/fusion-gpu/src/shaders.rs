//! The WGSL sources of every stage, compiled into the crate from the workspace's `shaders/`.

/// H1 back-projection (`main`).
pub const BACKPROJECT: &str = include_str!("../../../shaders/backproject.wgsl");
/// H2 transform + projection into the colour camera (`main`).
pub const PROJECT: &str = include_str!("../../../shaders/project.wgsl");
/// H7 z-buffer (`clear`, `scatter`).
pub const ZBUFFER: &str = include_str!("../../../shaders/zbuffer.wgsl");

/// Every shader as `(file name, source)`, for validation and tooling.
pub const ALL: &[(&str, &str)] = &[
    ("backproject.wgsl", BACKPROJECT),
    ("project.wgsl", PROJECT),
    ("zbuffer.wgsl", ZBUFFER),
];
