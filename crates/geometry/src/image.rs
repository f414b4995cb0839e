//! A minimal row-major image grid used by every pipeline stage.
//!
//! `Image<f32>` holds depth in metres (`NaN` = no sample), `Image<[u8; 3]>` RGB colour,
//! `Image<u8>` / `Image<bool>` masks. Pixel `(x, y)` is column `x`, row `y`, row 0 on top.

use crate::GeometryError;

/// A `width × height` grid of `T`, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    width: usize,
    height: usize,
    data: Vec<T>,
}

impl<T: Clone> Image<T> {
    /// An image filled with `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self { width, height, data: vec![value; width * height] }
    }
}

impl<T> Image<T> {
    /// Wraps row-major `data`; fails if its length is not `width * height`.
    pub fn from_vec(width: usize, height: usize, data: Vec<T>) -> Result<Self, GeometryError> {
        if data.len() != width * height {
            return Err(GeometryError::InvalidInput(format!(
                "image buffer holds {} values, a {width}x{height} image needs {}",
                data.len(),
                width * height
            )));
        }
        Ok(Self { width, height, data })
    }

    /// Builds an image by calling `f(x, y)` for every pixel.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> T) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self { width, height, data }
    }

    /// Width in pixels.
    #[inline]
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    #[inline]
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    #[inline]
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// The pixel at column `x`, row `y` (panics outside the image, like slice indexing).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> &T {
        &self.data[y * self.width + x]
    }

    /// Mutable pixel at column `x`, row `y`.
    #[inline]
    pub fn get_mut(&mut self, x: usize, y: usize) -> &mut T {
        &mut self.data[y * self.width + x]
    }

    /// The row-major pixels.
    #[inline]
    pub fn data(&self) -> &[T] {
        &self.data
    }

    /// The row-major pixels, mutable.
    #[inline]
    pub fn data_mut(&mut self) -> &mut [T] {
        &mut self.data
    }

    /// Takes the pixels out.
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }

    /// Row `y`.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// A new image with `f` applied to every pixel.
    pub fn map<U>(&self, f: impl FnMut(&T) -> U) -> Image<U> {
        Image { width: self.width, height: self.height, data: self.data.iter().map(f).collect() }
    }

    /// Fails with [`GeometryError::SizeMismatch`] unless the image is `width × height`.
    pub fn expect_size(
        &self,
        what: &str,
        width: usize,
        height: usize,
    ) -> Result<(), GeometryError> {
        if (self.width, self.height) == (width, height) {
            Ok(())
        } else {
            Err(GeometryError::SizeMismatch {
                what: what.to_string(),
                got_w: self.width,
                got_h: self.height,
                want_w: width,
                want_h: height,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn row_major_indexing_and_size_checks() {
        let img = Image::from_fn(3, 2, |x, y| 10 * y + x);
        assert_eq!(*img.get(2, 1), 12);
        assert_eq!(img.row(1), &[10, 11, 12]);
        let e = Image::from_vec(3, 2, vec![0u8; 5]).unwrap_err();
        assert!(matches!(e, GeometryError::InvalidInput(_)), "{e:?}");
        assert!(img.expect_size("test", 3, 2).is_ok());
        let e = img.expect_size("test", 2, 3).unwrap_err();
        assert!(
            matches!(
                e,
                GeometryError::SizeMismatch { got_w: 3, got_h: 2, want_w: 2, want_h: 3, .. }
            ),
            "{e:?}"
        );
    }
}
