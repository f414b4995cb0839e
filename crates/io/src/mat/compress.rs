//! Stage 3 of the reader: `miCOMPRESSED` elements (zlib, the default since MATLAB 7) inflated
//! into the bytes of the one element they hold.

use std::io::Read;

/// Inflates the zlib stream of one compressed element.
pub(super) fn inflate(data: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    flate2::read::ZlibDecoder::new(data)
        .read_to_end(&mut out)
        .map_err(|e| format!("compressed data is corrupt or truncated ({e})"))?;
    Ok(out)
}
