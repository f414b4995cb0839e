//! The checkerboard target and the corners seen in one view.

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::CalibError;

/// A checkerboard described by its *inner* corners (OpenCV's `patternSize`) and square length.
///
/// Board frame: origin at the first inner corner, corner `k` at
/// `(square·(k mod cols), square·(k div cols), 0)` metres; the top-left square (next to
/// corner 0, outside the inner grid) has the colour [`Board::top_left_black`]. The colouring
/// fixes the board's handedness and, on partial boards, which rows or columns are missing.
/// For odd × odd inner corners (7×5) the colouring is symmetric under a 180° turn and the
/// detector picks the placement by orientation; for one odd and one even count (9×6) the colour
/// decides (the corner ordering rule is in the `detect` module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Board {
    /// Inner corners per row (along the board's x axis).
    pub cols: usize,
    /// Inner corners per column (along the board's y axis).
    pub rows: usize,
    /// Square side, metres.
    pub square_m: f64,
    /// Colour of the board's top-left square (the one diagonal to corner 0): `Some(true)`
    /// black, `Some(false)` white, `None` unknown (the detector finds it from the images; a
    /// real board is never seen mirrored, so one colouring fits every view).
    #[serde(default)]
    pub top_left_black: Option<bool>,
}

impl Board {
    /// A board with `cols × rows` inner corners and squares of `square_m` metres.
    pub fn new(cols: usize, rows: usize, square_m: f64) -> Result<Self, CalibError> {
        if cols < 2 || rows < 2 {
            return Err(CalibError::InvalidArgument(format!(
                "board {cols}x{rows}: give the number of INNER corners, at least 2x2 (e.g. 7x5 for a board of 8x6 squares)"
            )));
        }
        if !(square_m.is_finite() && square_m > 0.0) {
            return Err(CalibError::InvalidArgument(format!(
                "square length {square_m} m must be positive"
            )));
        }
        Ok(Self { cols, rows, square_m, top_left_black: None })
    }

    /// Number of inner corners.
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// Always false (a board has at least 2x2 corners); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Board-frame position of corner `id` (metres, z = 0).
    pub fn object_point(&self, id: usize) -> Vector3<f64> {
        Vector3::new(
            self.square_m * (id % self.cols) as f64,
            self.square_m * (id / self.cols) as f64,
            0.0,
        )
    }
}

/// One detected corner: its index on the board (`k` as in [`Board::object_point`]) and its
/// sub-pixel position (0-based, pixel centres at integers).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Corner {
    /// Board index `k`.
    pub id: usize,
    /// Pixel position.
    pub px: Vector2<f64>,
}

/// The corners one image shows. Partial boards are allowed: only the corners whose label is
/// certain are listed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewCorners {
    /// Image name (for reports and error messages).
    pub name: String,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Labelled corners.
    pub corners: Vec<Corner>,
    /// Why the view cannot be used at all (e.g. the image could not be read), or `None`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unusable: Option<String>,
}

impl ViewCorners {
    /// Looks a corner up by board index.
    pub fn get(&self, id: usize) -> Option<Vector2<f64>> {
        self.corners.iter().find(|c| c.id == id).map(|c| c.px)
    }
}
