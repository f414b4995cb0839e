//! A frame's colour JPEG and its orientation. A recording keeps the sensor's JPEG, which is
//! mirrored left–right (`kinect_usb::orientation`); a capture folder's JPEG is as the scene is.
//! Every consumer (colour on the depth grid, the frame's colour file, the figures) gets the
//! scene orientation through [`ColorJpeg::decode`] or [`ColorJpeg::scene_jpeg`], and a
//! recording's JPEG is decoded or re-encoded only where an output needs it.

use std::borrow::Cow;

use geometry::Image;

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
    /// The colour image as the scene is. Error: the decoder's message.
    pub fn decode(&self) -> Result<Image<[u8; 3]>, String> {
        if self.mirrored {
            return kfuse_io::sensor_color::decode_mirrored(&self.bytes);
        }
        let img = image::load_from_memory_with_format(&self.bytes, image::ImageFormat::Jpeg)
            .map_err(|e| format!("the colour JPEG does not decode: {e}"))?
            .into_rgb8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let px = img.into_raw().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        Image::from_vec(w, h, px).map_err(|e| e.to_string())
    }

    /// A JPEG as the scene is: the bytes as read, or the sensor's frame mirrored and encoded
    /// anew (`kfuse_io::sensor_color::MIRRORED_JPEG_QUALITY`).
    pub fn scene_jpeg(&self) -> Result<Cow<'_, [u8]>, String> {
        if self.mirrored {
            kfuse_io::sensor_color::mirrored_jpeg(&self.bytes).map(Cow::Owned)
        } else {
            Ok(Cow::Borrowed(&self.bytes))
        }
    }
}
