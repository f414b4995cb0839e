//! The 2D panes as RGB images (pure functions: tested without a window).
//!
//! Depth colours: viridis (dark blue = near, yellow = far) over a robust range (2nd-98th
//! percentile), black = no sample: `kfuse_figures`' colour map and range, the same as the
//! `kfuse fuse` figures.

use geometry::Image;

use crate::data::Frame;
use crate::pipeline::Fused;

/// Side of one checkerboard square of the overlay, colour pixels: 64 px at 1920 wide gives
/// 30 columns, fine enough to compare edges and coarse enough to see both images.
pub const CHECKER_PX: usize = 64;

/// Opacity of the depth colours in the blend overlay: 0.5 weighs both images equally
/// (MATLAB `imshowpair(..., 'blend')`).
pub const BLEND_ALPHA: f32 = 0.5;

/// The 2D panes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Pane {
    /// Colour image (colour camera).
    Color,
    /// Input depth (depth camera), colour-mapped, with a legend.
    Depth,
    /// IR amplitude (depth camera).
    Ir,
    /// Registered depth blended over the colour image.
    Blend,
    /// Registered depth and colour in a checkerboard.
    Checker,
    /// H8 disocclusion holes over the colour image.
    Holes,
    /// H6 colour sampled on the depth grid.
    ColorOnDepth,
}

impl Pane {
    /// All panes in menu order.
    pub const ALL: [Pane; 7] = [
        Pane::Color,
        Pane::Depth,
        Pane::Ir,
        Pane::Blend,
        Pane::Checker,
        Pane::Holes,
        Pane::ColorOnDepth,
    ];

    /// The label of its button.
    pub fn label(self) -> &'static str {
        match self {
            Pane::Color => "Colour",
            Pane::Depth => "Depth",
            Pane::Ir => "IR",
            Pane::Blend => "Overlay: blend",
            Pane::Checker => "Overlay: checkerboard",
            Pane::Holes => "Hole mask",
            Pane::ColorOnDepth => "Colour on depth",
        }
    }

    /// True when the pane is on the depth camera's pixel grid (else the colour camera's).
    pub fn on_depth_grid(self) -> bool {
        matches!(self, Pane::Depth | Pane::Ir | Pane::ColorOnDepth)
    }
}

pub use kfuse_figures::{colormap, robust_range};

/// Depth as colours over `range` (metres); no sample = black ([`kfuse_figures::depth_colors`]).
pub fn depth_colors(depth: &Image<f32>, range: (f32, f32)) -> Image<[u8; 3]> {
    kfuse_figures::depth_colors(depth, Some(range))
}

/// An image of the pane, and the depth range its legend shows (metres), if any.
pub fn render(pane: Pane, frame: &Frame, fused: &Fused) -> (Image<[u8; 3]>, Option<(f32, f32)>) {
    let range = robust_range(frame.depth.data().iter().copied()).unwrap_or((0.0, 1.0));
    match pane {
        Pane::Color => (frame.color.clone(), None),
        Pane::Depth => (depth_colors(&frame.depth, range), Some(range)),
        Pane::Ir => {
            let ir = match &frame.ir {
                Some(ir) => ir,
                None => {
                    return (
                        Image::filled(frame.depth.width(), frame.depth.height(), [0, 0, 0]),
                        None,
                    );
                }
            };
            let (lo, hi) = robust_range(ir.data().iter().copied()).unwrap_or((0.0, 1.0));
            (
                ir.map(|&a| {
                    if a.is_finite() {
                        let g = ((a - lo) / (hi - lo)).clamp(0.0, 1.0).sqrt() * 255.0;
                        [g as u8; 3]
                    } else {
                        [0; 3]
                    }
                }),
                None,
            )
        }
        Pane::Blend => {
            let d = depth_colors(&fused.shown_depth, range);
            let out = Image::from_fn(d.width(), d.height(), |x, y| {
                let c = frame.color.get(x, y);
                if fused.shown_depth.get(x, y).is_finite() {
                    let dc = d.get(x, y);
                    [0, 1, 2].map(|k| {
                        (BLEND_ALPHA * dc[k] as f32 + (1.0 - BLEND_ALPHA) * c[k] as f32).round()
                            as u8
                    })
                } else {
                    *c
                }
            });
            (out, Some(range))
        }
        Pane::Checker => {
            let d = depth_colors(&fused.shown_depth, range);
            let out = Image::from_fn(d.width(), d.height(), |x, y| {
                if (x / CHECKER_PX + y / CHECKER_PX).is_multiple_of(2) {
                    *frame.color.get(x, y)
                } else {
                    *d.get(x, y)
                }
            });
            (out, Some(range))
        }
        Pane::Holes => {
            let mask = &fused.output.hole_mask;
            let out = Image::from_fn(mask.width(), mask.height(), |x, y| {
                let c = frame.color.get(x, y);
                let g = ((c[0] as u32 + c[1] as u32 + c[2] as u32) / 6) as u8;
                if *mask.get(x, y) { [255, 40, 40] } else { [g, g, g] }
            });
            (out, None)
        }
        Pane::ColorOnDepth => {
            let o = &fused.output;
            (
                Image::from_fn(o.color_on_depth.width(), o.color_on_depth.height(), |x, y| {
                    if *o.color_on_depth_valid.get(x, y) {
                        *o.color_on_depth.get(x, y)
                    } else {
                        [0, 0, 0]
                    }
                }),
                None,
            )
        }
    }
}

/// What the cursor is on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Probe {
    /// Pixel (column, row) on the pane's grid.
    pub pixel: [usize; 2],
    /// Depth there, millimetres (camera `z`), if there is a sample.
    pub depth_mm: Option<f32>,
    /// The 3D point, metres, in that camera's frame (depth camera for depth-grid panes,
    /// colour camera otherwise).
    pub point: Option<[f64; 3]>,
}

/// The value under pixel `(x, y)` of `pane` (continuous pixel coordinates, centres at
/// integers); `None` outside the image.
pub fn probe(pane: Pane, frame: &Frame, fused: &Fused, x: f32, y: f32) -> Option<Probe> {
    let (cam, w, h) = if pane.on_depth_grid() {
        (&frame.rig.depth, frame.rig.depth.width, frame.rig.depth.height)
    } else {
        (&frame.rig.color, frame.rig.color.width, frame.rig.color.height)
    };
    let (px, py) = ((x + 0.5).floor(), (y + 0.5).floor());
    if !(px >= 0.0 && py >= 0.0 && (px as usize) < w && (py as usize) < h) {
        return None;
    }
    let (px, py) = (px as usize, py as usize);
    let (point, z) = if pane.on_depth_grid() {
        let value = *frame.depth.get(px, py) as f64;
        let p = (value.is_finite() && value > 0.0)
            .then(|| cam.backproject(px as f64, py as f64, value, frame.kind))
            .flatten();
        (p, p.map(|p| p.z))
    } else {
        let z = *fused.shown_depth.get(px, py) as f64;
        let p = z
            .is_finite()
            .then(|| cam.backproject(px as f64, py as f64, z, geometry::DepthKind::Z))
            .flatten();
        (p, p.map(|p| p.z))
    };
    Some(Probe {
        pixel: [px, py],
        depth_mm: z.map(|z| (z * 1000.0) as f32),
        point: point.map(|p| [p.x, p.y, p.z]),
    })
}
