//! Stage 4 of the reader: one `miMATRIX` element (array flags, dimensions, name, then the
//! numeric / char / struct / cell content, recursively) → `(name, MatValue)`.

use super::element::{class_size, decode_ints, decode_with, read_numeric, stored_size};
use super::header::*;
use super::value::{MatClass, MatValue, NumericArray, NumericData, StructArray, dims_text};

/// Largest array, in bytes once in memory, the reader builds: 128 MiB. The largest variable of
/// the lab's files is a 1920×1080×3 colour image, 50 MB even as `double`; a declared size
/// beyond this is a corrupt or crafted header, refused before anything is allocated (MATLAB
/// stores integer-valued doubles as `uint8`, so a small element can legally declare 8× its
/// bytes: this bound keeps that widening finite).
pub const MAX_ARRAY_BYTES: usize = 128 << 20;
/// Most elements of a struct array without fields: such an array carries no data, so its
/// size cannot be checked against the bytes present; no real file has more than a few.
const MAX_EMPTY_STRUCT_ELEMENTS: usize = 1 << 16;
/// Bytes of the smallest sub-element (a tag) every struct field value and every cell needs.
const TAG_BYTES: usize = 8;

/// `name` as it can be printed in one line of an error message: MATLAB names are ASCII letters,
/// digits and `_` (63 at most); anything else in a corrupt file is escaped, and the length cut.
pub(super) fn printable(name: &str) -> String {
    let mut out: String = name.chars().take(64).flat_map(char::escape_default).collect();
    if name.chars().count() > 64 {
        out.push('…');
    }
    out
}

/// Parses the content of an `miMATRIX` element into `(name, value)`.
pub(super) fn parse_matrix(
    data: &[u8],
    little: bool,
    depth: usize,
) -> Result<(String, MatValue), String> {
    if depth > MAX_DEPTH {
        return Err(format!("structs/cells nested deeper than {MAX_DEPTH} levels"));
    }
    if data.is_empty() {
        // MATLAB writes an empty array ([]) as an miMATRIX with no content.
        return Ok((
            String::new(),
            MatValue::Numeric(NumericArray {
                dims: vec![0, 0],
                real: NumericData::Double(Vec::new()),
                imag: None,
            }),
        ));
    }
    let mut r = Reader { bytes: data, pos: 0, little };
    let (ty, flags) = r.element()?;
    if ty != MI_UINT32 || flags.len() < 8 {
        return Err("array flags missing (corrupt array header)".into());
    }
    let flags_word = r_u32(flags, little);
    let class = MatClass::from_code((flags_word & 0xff) as u8);
    let complex = flags_word & 0x800 != 0;
    let logical = flags_word & 0x200 != 0;
    let (ty, dims_raw) = r.element()?;
    if ty != MI_INT32 {
        return Err("array dimensions missing (corrupt array header)".into());
    }
    if dims_raw.len() > MAX_DIMS * 4 {
        return Err(format!("array has more than {MAX_DIMS} dimensions (corrupt array header)"));
    }
    let dims: Vec<usize> = decode_ints(ty, dims_raw, little)
        .map_err(|e| format!("array dimensions: {e}"))?
        .into_iter()
        .map(|d| usize::try_from(d).map_err(|_| format!("negative dimension {d}")))
        .collect::<Result<_, _>>()?;
    if dims.len() < 2 || dims.len() > MAX_DIMS {
        return Err(format!("array has {} dimensions (2..{MAX_DIMS} allowed)", dims.len()));
    }
    let count = dims
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| format!("array dimensions {} overflow", dims_text(&dims)))?;
    let (ty, name_raw) = r.element()?;
    if ty != MI_INT8 && ty != MI_UINT8 {
        return Err("array name missing (corrupt array header)".into());
    }
    let name = String::from_utf8_lossy(name_raw).into_owned();
    let shown = printable(&name);
    let at = |what: &str| format!("'{shown}' ({what})");
    // What the content that follows the header must at least hold, checked before anything
    // is allocated: the declared dimensions against the limit and the bytes present.
    let too_big = |what: &str, need: usize, remaining: usize| {
        format!(
            "{}: dimensions {} need {need} bytes but only {remaining} remain (corrupt or crafted header)",
            at(what),
            dims_text(&dims)
        )
    };
    let value = match class {
        MatClass::Double
        | MatClass::Single
        | MatClass::Int8
        | MatClass::UInt8
        | MatClass::Int16
        | MatClass::UInt16
        | MatClass::Int32
        | MatClass::UInt32
        | MatClass::Int64
        | MatClass::UInt64 => {
            let bytes = count.saturating_mul(class_size(class, logical));
            if bytes > MAX_ARRAY_BYTES {
                return Err(format!(
                    "{}: dimensions {} make a {bytes}-byte array, over the {MAX_ARRAY_BYTES}-byte limit (corrupt file?)",
                    at("real part"),
                    dims_text(&dims)
                ));
            }
            let mut read_part = |what: &str| -> Result<NumericData, String> {
                let (ty, raw) = r.element().map_err(|e| format!("{}: {e}", at(what)))?;
                let size = stored_size(ty).ok_or_else(|| {
                    format!("{}: unknown data type {ty} in a numeric element", at(what))
                })?;
                if raw.len() != count.saturating_mul(size) {
                    return Err(format!(
                        "{}: {} values for dimensions {}",
                        at(what),
                        raw.len() / size,
                        dims_text(&dims)
                    ));
                }
                read_numeric(ty, raw, little, class, logical)
                    .map_err(|e| format!("{}: {e}", at(what)))
            };
            let real = read_part("real part")?;
            let imag = if complex { Some(read_part("imaginary part")?) } else { None };
            MatValue::Numeric(NumericArray { dims, real, imag })
        }
        MatClass::Char => {
            let (ty, raw) = r.element().map_err(|e| format!("{}: {e}", at("text")))?;
            let units: Vec<u16> = if ty == MI_UTF8 {
                let text = String::from_utf8_lossy(raw);
                text.encode_utf16().collect()
            } else {
                if matches!(ty, MI_SINGLE | MI_DOUBLE) {
                    return Err(format!("{}: characters stored as floating point", at("text")));
                }
                decode_with(ty, raw, little, |c| c as u16, |c| c as u16)
                    .map_err(|e| format!("{}: {e}", at("text")))?
            };
            if units.len() != count && ty != MI_UTF8 {
                return Err(format!(
                    "{}: {} characters for dimensions {}",
                    at("text"),
                    units.len(),
                    dims_text(&dims)
                ));
            }
            MatValue::Char { dims, units }
        }
        MatClass::Struct => {
            let (ty, len_raw) =
                r.element().map_err(|e| format!("{}: {e}", at("field name length")))?;
            let name_len = match (len_raw.len() <= 8).then(|| decode_ints(ty, len_raw, little)) {
                Some(Ok(v)) if v.len() == 1 && v[0] > 0 => v[0] as usize,
                _ => return Err(format!("{}: bad field name length", at("struct"))),
            };
            let (_, names_raw) = r.element().map_err(|e| format!("{}: {e}", at("field names")))?;
            let field_names: Vec<String> = names_raw
                .chunks(name_len)
                .map(|c| String::from_utf8_lossy(c).trim_end_matches('\0').to_string())
                .collect();
            let remaining = data.len().saturating_sub(r.pos);
            if field_names.is_empty() {
                if count > MAX_EMPTY_STRUCT_ELEMENTS {
                    return Err(format!(
                        "{}: {count} elements without fields (more than {MAX_EMPTY_STRUCT_ELEMENTS}; corrupt header?)",
                        at("struct")
                    ));
                }
            } else {
                let need = count.saturating_mul(field_names.len()).saturating_mul(TAG_BYTES);
                if need > remaining {
                    return Err(too_big("struct", need, remaining));
                }
            }
            let mut elements = Vec::with_capacity(count);
            for _ in 0..count {
                let mut values = Vec::with_capacity(field_names.len());
                for f in &field_names {
                    let (ty, sub) =
                        r.element().map_err(|e| format!("'{shown}.{}': {e}", printable(f)))?;
                    if ty != MI_MATRIX {
                        return Err(format!(
                            "'{shown}.{}': field is not an array element",
                            printable(f)
                        ));
                    }
                    let (_, v) = parse_matrix(sub, little, depth + 1)
                        .map_err(|e| format!("'{shown}.{}': {e}", printable(f)))?;
                    values.push(v);
                }
                elements.push(values);
            }
            MatValue::Struct(StructArray { dims, field_names, elements })
        }
        MatClass::Cell => {
            let need = count.saturating_mul(TAG_BYTES);
            let remaining = data.len().saturating_sub(r.pos);
            if need > remaining {
                return Err(too_big("cell", need, remaining));
            }
            let mut cells = Vec::with_capacity(count);
            for i in 0..count {
                let (ty, sub) = r.element().map_err(|e| format!("'{shown}{{{}}}': {e}", i + 1))?;
                if ty != MI_MATRIX {
                    return Err(format!("'{shown}{{{}}}': cell is not an array element", i + 1));
                }
                let (_, v) = parse_matrix(sub, little, depth + 1)
                    .map_err(|e| format!("'{shown}{{{}}}': {e}", i + 1))?;
                cells.push(v);
            }
            MatValue::Cell { dims, cells }
        }
        other => MatValue::Unsupported { class: other },
    };
    Ok((name, value))
}
