//! Raw depth frame layout (§8): 10 sub-images of 424 stored rows × 512 packed 11-bit codes,
//! the column/row permutations and the companding LUT.

/// Image width of the depth/IR camera.
pub const WIDTH: usize = 512;
/// Image height of the depth/IR camera.
pub const HEIGHT: usize = 424;
/// Pixels per depth image.
pub const PIXELS: usize = WIDTH * HEIGHT;
/// Bytes of one stored row (512 codes × 11 bits).
pub const ROW_BYTES: usize = 704;
/// Bytes of one sub-image.
pub const SUB_IMAGE_BYTES: usize = ROW_BYTES * HEIGHT;
/// Sub-images per raw frame (9 phase images + 1 unused).
pub const SUB_IMAGES: usize = 10;
/// Bytes of one raw frame.
pub const RAW_FRAME_BYTES: usize = SUB_IMAGE_BYTES * SUB_IMAGES;
/// The LUT value marking a saturated measurement (code 1024).
pub const SATURATED: i16 = 32767;
/// The saturation code.
pub const SATURATION_CODE: u16 = 1024;

/// Storage slot of image column `c` within a stored row.
#[inline]
pub fn slot_of_column(c: usize) -> usize {
    (c >> 2) + 128 * (c & 3)
}

/// Image column stored in slot `q` (inverse of [`slot_of_column`]).
#[inline]
pub fn column_of_slot(q: usize) -> usize {
    4 * (q & 127) + (q >> 7)
}

/// Stored row holding upright output row `r`.
#[inline]
pub fn stored_row_of_output_row(r: usize) -> usize {
    if r <= 211 { r } else { 635 - r }
}

/// Stored row holding *processing* row `y` (`y = 423 − r`).
#[inline]
pub fn stored_row_of_processing_row(y: usize) -> usize {
    if y < 212 { y + 212 } else { 423 - y }
}

/// The 2048-entry code → signed measurement table (protocol §8).
pub fn lut() -> [i16; 2048] {
    let mut t = [0i16; 2048];
    let mut y: i32 = 0;
    for c in 0..1024usize {
        t[c] = y as i16;
        t[1024 + c] = (-y) as i16;
        let shift = ((c / 128) as i32 - 1).max(0);
        y += 1 << shift;
    }
    t[1024] = SATURATED;
    t
}

/// Nearest non-saturating 11-bit code for a measurement value (the inverse of [`lut`], used by
/// the forward model). Ties go to the smaller magnitude.
pub fn encode(value: f64, table: &[i16; 2048]) -> u16 {
    let mag = value.abs();
    // Binary search over the increasing magnitudes LUT[0..1024].
    let (mut lo, mut hi) = (0usize, 1023usize);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if (table[mid] as f64) < mag { lo = mid + 1 } else { hi = mid }
    }
    let mut best = lo;
    if lo > 0 && (mag - table[lo - 1] as f64) <= (table[lo] as f64 - mag) {
        best = lo - 1;
    }
    if value < 0.0 && best != 0 { (1024 + best) as u16 } else { best as u16 }
}

/// Reads the 11-bit code in `slot` of a 704-byte stored row.
#[inline]
pub fn read_code(row: &[u8], slot: usize) -> u16 {
    let bit = 11 * slot;
    let byte = bit >> 3;
    let b0 = row[byte] as u32;
    let b1 = row.get(byte + 1).copied().unwrap_or(0) as u32;
    let b2 = if byte + 2 < ROW_BYTES { row[byte + 2] as u32 } else { 0 };
    (((b0 | (b1 << 8) | (b2 << 16)) >> (bit & 7)) & 0x7FF) as u16
}

/// Writes an 11-bit code into `slot` of a 704-byte stored row.
#[inline]
pub fn write_code(row: &mut [u8], slot: usize, code: u16) {
    let bit = 11 * slot;
    for k in 0..11 {
        let n = bit + k;
        let mask = 1u8 << (n & 7);
        if (code >> k) & 1 == 1 { row[n >> 3] |= mask } else { row[n >> 3] &= !mask }
    }
}

/// Packs nine (or ten) upright code images (`codes[s][r*512 + c]`) into a raw frame.
/// Sub-images not given are left zero.
pub fn pack_frame(codes: &[Vec<u16>], out: &mut [u8]) {
    assert_eq!(out.len(), RAW_FRAME_BYTES, "raw frame buffer size");
    out.fill(0);
    for (s, img) in codes.iter().enumerate().take(SUB_IMAGES) {
        for r in 0..HEIGHT {
            let i = stored_row_of_output_row(r);
            let row = &mut out[s * SUB_IMAGE_BYTES + i * ROW_BYTES..][..ROW_BYTES];
            for c in 0..WIDTH {
                write_code(row, slot_of_column(c), img[r * WIDTH + c] & 0x7FF);
            }
        }
    }
}

/// Unpacks sub-image `s` of a raw frame into an upright code image.
pub fn unpack_sub_image(frame: &[u8], s: usize) -> Vec<u16> {
    let mut img = vec![0u16; PIXELS];
    for r in 0..HEIGHT {
        let i = stored_row_of_output_row(r);
        let row = &frame[s * SUB_IMAGE_BYTES + i * ROW_BYTES..][..ROW_BYTES];
        for c in 0..WIDTH {
            img[r * WIDTH + c] = read_code(row, slot_of_column(c));
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permutations_are_bijections() {
        let mut seen = [false; 512];
        for c in 0..512 {
            let q = slot_of_column(c);
            assert!(!seen[q]);
            seen[q] = true;
            assert_eq!(column_of_slot(q), c);
        }
        let mut rows = [false; 424];
        for r in 0..424 {
            let i = stored_row_of_output_row(r);
            assert!(!rows[i]);
            rows[i] = true;
            assert_eq!(stored_row_of_processing_row(423 - r), i);
        }
        // Protocol §8: output row r ≥ 212 is stored row 635 − r, so row 423 is stored row 212.
        assert_eq!(stored_row_of_output_row(423), 212);
    }

    #[test]
    fn lut_properties() {
        let t = lut();
        // Protocol §8: the companded magnitude's largest value is 16 320; code 1024 is the
        // saturation marker.
        assert_eq!(t[1023], 16320);
        assert_eq!(t[1024], SATURATED);
        for c in 1..1024 {
            assert!(t[c] > t[c - 1]);
            assert_eq!(t[1024 + c], -t[c]);
            assert_eq!(encode(t[c] as f64, &t) as usize, c);
            assert_eq!(encode(t[1024 + c] as f64, &t) as usize, 1024 + c);
        }
        assert_eq!(encode(0.0, &t), 0);
    }
}
