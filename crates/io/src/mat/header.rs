//! Stage 1 of the reader: the 128-byte file header (text, version, byte order) and the tags of
//! data elements (type + byte count, the "small data element" form, 8-byte padding).

/// Size of the text + subsystem + version + endian header of every v5 file.
pub(super) const HEADER_LEN: usize = 128;
/// Largest number of dimensions accepted; MATLAB arrays rarely exceed 4, 32 guards against
/// garbage tags describing absurd shapes.
pub(super) const MAX_DIMS: usize = 32;
/// Deepest nesting of structs / cells accepted (protects the stack from crafted files).
pub(super) const MAX_DEPTH: usize = 64;

// Data types of data elements (MAT-File Format, table 1-1).
pub(super) const MI_INT8: u32 = 1;
pub(super) const MI_UINT8: u32 = 2;
pub(super) const MI_INT16: u32 = 3;
pub(super) const MI_UINT16: u32 = 4;
pub(super) const MI_INT32: u32 = 5;
pub(super) const MI_UINT32: u32 = 6;
pub(super) const MI_SINGLE: u32 = 7;
pub(super) const MI_DOUBLE: u32 = 9;
pub(super) const MI_INT64: u32 = 12;
pub(super) const MI_UINT64: u32 = 13;
pub(super) const MI_MATRIX: u32 = 14;
pub(super) const MI_COMPRESSED: u32 = 15;
pub(super) const MI_UTF8: u32 = 16;
pub(super) const MI_UTF16: u32 = 17;
pub(super) const MI_UTF32: u32 = 18;

pub(super) struct Reader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) pos: usize,
    pub(super) little: bool,
}

impl<'a> Reader<'a> {
    fn u32_at(&self, at: usize) -> Result<u32, String> {
        let b = self.bytes.get(at..at + 4).ok_or_else(|| {
            format!(
                "truncated: a data element tag at byte {at} runs past the end ({} bytes)",
                self.bytes.len()
            )
        })?;
        let arr = [b[0], b[1], b[2], b[3]];
        Ok(if self.little { u32::from_le_bytes(arr) } else { u32::from_be_bytes(arr) })
    }

    /// Reads one data element (tag + data, skipping padding): `(type, data bytes)`.
    pub(super) fn element(&mut self) -> Result<(u32, &'a [u8]), String> {
        let first = self.u32_at(self.pos)?;
        // Small data element: the upper 16 bits hold the byte count, data in the tag itself.
        let small_len = if self.little { first >> 16 } else { first & 0xffff };
        let small_type = if self.little { first & 0xffff } else { first >> 16 };
        if small_len != 0 && small_len <= 4 {
            let start = self.pos + 4;
            let end = start + small_len as usize;
            let data = self.bytes.get(start..end).ok_or("truncated small data element")?;
            self.pos += 8;
            if self.pos > self.bytes.len() {
                return Err("truncated small data element".into());
            }
            return Ok((small_type, data));
        }
        let ty = first;
        let n = self.u32_at(self.pos + 4)? as usize;
        let start = self.pos + 8;
        let end = start.checked_add(n).ok_or("element size overflows")?;
        if end > self.bytes.len() {
            return Err(format!(
                "truncated: element of type {ty} at byte {} claims {n} bytes, only {} remain (the file was cut short?)",
                self.pos,
                self.bytes.len().saturating_sub(start)
            ));
        }
        let data = &self.bytes[start..end];
        // Elements are padded to 8 bytes, except compressed ones.
        self.pos = if ty == MI_COMPRESSED { end } else { end.div_ceil(8) * 8 };
        self.pos = self.pos.min(self.bytes.len());
        Ok((ty, data))
    }
}

pub(super) fn r_u32(b: &[u8], little: bool) -> u32 {
    let arr = [b[0], b[1], b[2], b[3]];
    if little { u32::from_le_bytes(arr) } else { u32::from_be_bytes(arr) }
}

/// Checks the 128-byte header: returns its descriptive text and whether the file is
/// little-endian.
pub(super) fn parse_header(bytes: &[u8]) -> Result<(String, bool), String> {
    if bytes.len() < HEADER_LEN {
        return Err(format!(
            "not a MATLAB v5 .mat file: {} bytes, shorter than the 128-byte header",
            bytes.len()
        ));
    }
    if bytes.starts_with(b"\x89HDF")
        || bytes[..HEADER_LEN.min(bytes.len())].windows(4).any(|w| w == b"HDF5")
    {
        return Err(
            "is a MATLAB v7.3 (HDF5) file, which is not supported: re-save it in MATLAB with save(..., '-v7')".into(),
        );
    }
    let header = String::from_utf8_lossy(&bytes[..116]).trim_end_matches([' ', '\0']).to_string();
    let little = match &bytes[126..128] {
        b"IM" => true,
        b"MI" => false,
        _ => return Err(format!("{}; expected the 'MATLAB 5.0 MAT-file' header", not_mat(bytes))),
    };
    if !header.starts_with("MATLAB") {
        return Err("not a MATLAB v5 .mat file: header does not start with 'MATLAB'".into());
    }
    Ok((header, little))
}

/// What a file that is not a `.mat` file looks like, for the one-line error: a known image or
/// archive kind by its signature, the start of a text file (printable ASCII only, at most 40
/// characters), or "binary data" — never the file's raw bytes.
fn not_mat(bytes: &[u8]) -> String {
    const KINDS: [(&[u8], &str); 9] = [
        (b"\x89PNG\r\n\x1a\n", "a PNG image"),
        (b"\xff\xd8\xff", "a JPEG image"),
        (b"II*\0", "a TIFF image"),
        (b"MM\0*", "a TIFF image"),
        (b"\x76\x2f\x31\x01", "an OpenEXR image"),
        (b"BM", "a BMP image"),
        (b"PK\x03\x04", "a zip archive"),
        (b"\x1f\x8b", "a gzip file"),
        (b"KFUSEREC", "a kfuse recording (.kfrec)"),
    ];
    if let Some((_, kind)) = KINDS.iter().find(|(magic, _)| bytes.starts_with(magic)) {
        return format!("is {kind}, not a MATLAB .mat file");
    }
    let start = &bytes[..bytes.len().min(40)];
    let printable = |b: &u8| b.is_ascii_graphic() || *b == b' ';
    if !start.is_empty() && start.iter().all(|b| printable(b) || b.is_ascii_whitespace()) {
        let text: String =
            start.iter().map(|&b| if printable(&b) { b as char } else { ' ' }).collect();
        return format!("not a MATLAB v5 .mat file (it starts with '{}')", text.trim());
    }
    "not a MATLAB v5 .mat file (binary data of another kind)".into()
}
