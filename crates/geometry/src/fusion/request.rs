//! The one front door into fusion: a [`Request`] owns the rig as fused (rectification
//! applied once), the depth kind, the [`FusionOptions`] and the one depth preparation every
//! caller uses ([`Request::prepare_depth`]: the rig's depth correction). [`Request::params`]
//! gives the per-pixel stages' whole [`PixelParams`], H1's sample rule (the depth range)
//! included; [`super::run_on`], [`super::stream_on`] and the several-Kinect fusion take it.
//!
//! A door (`kfuse fuse` for one frame, several Kinects or a sequence, the viewer, the Python
//! package) maps its arguments to a request, prepares each frame's depth (metres, the unit
//! its reader gives) with it and hands both to the engine.

use super::{FusionOptions, PixelParams};
use crate::{DepthKind, GeometryError, Image, Rig};

/// What to fuse and how (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    rig: Rig,
    kind: DepthKind,
    options: FusionOptions,
}

impl Request {
    /// The request for frames of `rig` (undistorted once here when `rig.rectified`: its
    /// images are already rectified), depth of kind `kind`, fused with `options`.
    ///
    /// The rig and the options' limits are checked where the work starts
    /// ([`super::run_on`], [`super::stream_on`]: [`super::check_inputs`],
    /// [`super::checked_coverage_radius_px`]), so that a door checks them first with its own
    /// words.
    ///
    /// Error ([`GeometryError::InvalidInput`]): a rig with a depth correction (a model of z
    /// depth) for range depth.
    pub fn new(rig: &Rig, kind: DepthKind, options: FusionOptions) -> Result<Self, GeometryError> {
        if rig.depth_correction.is_some() && kind != DepthKind::Z {
            return Err(GeometryError::InvalidInput(DEPTH_CORRECTION_NEEDS_Z.into()));
        }
        let rig = if rig.rectified { rig.as_rectified() } else { rig.clone() };
        Ok(Self { rig, kind, options })
    }

    /// The rig as fused (without distortion when its images are rectified).
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// What the depth images hold.
    pub fn kind(&self) -> DepthKind {
        self.kind
    }

    /// The options.
    pub fn options(&self) -> &FusionOptions {
        &self.options
    }

    /// The per-pixel stages' parameters, H1's sample rule included ([`PixelParams::new`] of the
    /// fused rig and the options). Every engine, the GPU included, receives these.
    pub fn params(&self) -> PixelParams {
        PixelParams::new(&self.rig, &self.options)
    }

    /// The one depth preparation: `depth` (metres, the rig's depth size) with the rig's depth
    /// correction (`kfuse calibrate --depth`, [`crate::DepthCorrection::correct_image`])
    /// applied. Returns the number of samples corrected (0 without a correction). The depth
    /// range is not applied here but by H1 on the engine ([`PixelParams::depth_range`]), so
    /// that it holds for depth decoded on the GPU too.
    ///
    /// Error: the correction's ([`GeometryError::SizeMismatch`] for a depth image of another
    /// size than the correction's).
    pub fn prepare_depth(&self, depth: &mut Image<f32>) -> Result<usize, GeometryError> {
        #[cfg(feature = "fault-injection")]
        if super::pipeline::fault::depth_preparation_broken() {
            fault_depth(depth);
        }
        match &self.rig.depth_correction {
            Some(c) => c.correct_image(depth, 1.0),
            None => Ok(0),
        }
    }

    /// `depth` prepared ([`Request::prepare_depth`]): borrowed when the preparation changes
    /// nothing, else a prepared copy.
    ///
    /// Error: the preparation's.
    pub fn prepared<'a>(
        &self,
        depth: &'a Image<f32>,
    ) -> Result<std::borrow::Cow<'a, Image<f32>>, GeometryError> {
        if !self.prepares_depth() {
            return Ok(std::borrow::Cow::Borrowed(depth));
        }
        let mut depth = depth.clone();
        self.prepare_depth(&mut depth)?;
        Ok(std::borrow::Cow::Owned(depth))
    }

    /// Whether [`Request::prepare_depth`] changes a depth image (a rig with a depth
    /// correction): a caller that would decode depth where it cannot prepare it (on the GPU)
    /// decodes it on the CPU instead.
    pub fn prepares_depth(&self) -> bool {
        #[cfg(feature = "fault-injection")]
        if super::pipeline::fault::depth_preparation_broken() {
            return true;
        }
        self.rig.depth_correction.is_some()
    }
}

/// Why a rig's depth correction cannot apply to range depth.
pub const DEPTH_CORRECTION_NEEDS_Z: &str = "the rig has a depth_correction (of z depth) but the \
     depth is --depth-kind range; fuse z depth, or remove the rig's depth_correction";

/// The broken preparation of the fault-injection feature: every sample 2 % farther.
#[cfg(feature = "fault-injection")]
fn fault_depth(depth: &mut Image<f32>) {
    for v in depth.data_mut() {
        *v *= 1.02;
    }
}
