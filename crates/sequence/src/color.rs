//! A frame's colour JPEG and its orientation. A recording keeps the sensor's JPEG, which is
//! mirrored left–right (`kinect_usb::orientation`); a capture folder's JPEG is as the scene is.
//! Every consumer (colour on the depth grid, the frame's colour file, the figures) gets the
//! scene orientation through [`ColorJpeg::decode`] or [`ColorJpeg::scene_jpeg`], and a
//! recording's JPEG is decoded only where an output needs its pixels, and flipped in the DCT
//! domain where an output is a JPEG. Decoding goes
//! through `kfuse_io::images`' one reader and its checks (a JPEG cut short is refused).

use std::borrow::Cow;
use std::path::Path;

use geometry::Image;

use crate::{Result, SequenceError};

/// A colour JPEG as read, and whether it is mirrored (the sensor's stream).
#[derive(Debug, Clone, PartialEq)]
pub struct ColorJpeg {
    /// The JPEG bytes as read.
    pub bytes: Vec<u8>,
    /// True for the sensor's stream (a recording), mirrored left–right; false for a file that
    /// is as the scene is (a capture folder).
    pub mirrored: bool,
}

impl ColorJpeg {
    /// The colour image as the scene is; `name` (the file, or the frame) is named in errors.
    pub fn decode(&self, name: &Path) -> Result<Image<[u8; 3]>> {
        let (mut img, note) = kfuse_io::images::decode_color_noting(name, &self.bytes)?;
        if let Some(note) = note {
            // The note names the file itself.
            let prefix = format!("{}: ", name.display());
            return Err(SequenceError::input(name, note.trim_start_matches(&prefix)));
        }
        if self.mirrored {
            let (w, _) = img.size();
            kinect_usb::orientation::mirror_rows(img.data_mut(), w);
        }
        Ok(img)
    }

    /// A JPEG as the scene is: the bytes as read (checked), or the sensor's frame mirrored
    /// without loss in the DCT domain (`kfuse_io::sensor_color::mirrored_jpeg`: the bytes
    /// `jpegtran -flip horizontal` writes; nothing is decoded or quantised again).
    pub fn scene_jpeg(&self, name: &Path) -> Result<Cow<'_, [u8]>> {
        if !self.mirrored {
            kfuse_io::images::check_picture(name, &self.bytes)?;
            return Ok(Cow::Borrowed(&self.bytes));
        }
        kfuse_io::sensor_color::mirrored_jpeg(&self.bytes).map(Cow::Owned).map_err(|m| {
            // The message names "the sensor's colour frame"; say which frame.
            SequenceError::input(name, m)
        })
    }
}
