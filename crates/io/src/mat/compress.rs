//! Stage 3 of the reader: `miCOMPRESSED` elements (zlib, the default since MATLAB 7) inflated
//! into the bytes of the one element they hold.
//!
//! Inflation is streamed with a cap ([`MAX_INFLATED_BYTES`]): a zlib bomb (a few hundred bytes
//! that inflate to gigabytes) stops at the cap with an error instead of taking the memory.

use std::io::Read;

use super::array::MAX_ARRAY_BYTES;

/// Largest inflated size of one compressed element: the largest array the reader builds
/// ([`MAX_ARRAY_BYTES`], 128 MiB) plus 1 MiB for its tags, name and padding. Anything larger
/// could not be read as an array anyway.
pub const MAX_INFLATED_BYTES: u64 = MAX_ARRAY_BYTES as u64 + (1 << 20);

/// Inflates the zlib stream of one compressed element, refusing more than `cap` bytes.
pub(super) fn inflate(data: &[u8], cap: u64) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    flate2::read::ZlibDecoder::new(data)
        .take(cap + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("compressed data is corrupt or truncated ({e})"))?;
    if out.len() as u64 > cap {
        return Err(format!(
            "compressed data inflates to more than {cap} bytes (the limit for one variable); corrupt file or a zlib bomb"
        ));
    }
    Ok(out)
}
