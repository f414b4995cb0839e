//! Stage 4 of the reader: one `miMATRIX` element (array flags, dimensions, name, then the
//! numeric / char / struct / cell content, recursively) → `(name, MatValue)`.

use super::element::{Stored, convert, decode};
use super::header::*;
use super::value::{MatClass, MatValue, NumericArray, NumericData, StructArray, dims_text};

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
    let dims: Vec<usize> = match decode(ty, dims_raw, little)? {
        Stored::Ints(v) => v
            .into_iter()
            .map(|d| usize::try_from(d).map_err(|_| format!("negative dimension {d}")))
            .collect::<Result<_, _>>()?,
        _ => return Err("array dimensions are not integers".into()),
    };
    if dims.len() < 2 || dims.len() > MAX_DIMS {
        return Err(format!("array has {} dimensions (2..{MAX_DIMS} allowed)", dims.len()));
    }
    let count = dims
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or("array dimensions overflow")?;
    let (ty, name_raw) = r.element()?;
    if ty != MI_INT8 && ty != MI_UINT8 {
        return Err("array name missing (corrupt array header)".into());
    }
    let name = String::from_utf8_lossy(name_raw).into_owned();
    let at = |what: &str| format!("'{name}' ({what})");
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
            let (ty, re) = r.element().map_err(|e| format!("{}: {e}", at("real part")))?;
            let real = convert(
                decode(ty, re, little).map_err(|e| format!("{}: {e}", at("real part")))?,
                class,
                logical,
            )?;
            if real.len() != count {
                return Err(format!(
                    "{}: {} values for dimensions {}",
                    at("real part"),
                    real.len(),
                    dims_text(&dims)
                ));
            }
            let imag = if complex {
                let (ty, im) = r.element().map_err(|e| format!("{}: {e}", at("imaginary part")))?;
                let imag = convert(decode(ty, im, little)?, class, logical)?;
                if imag.len() != count {
                    return Err(format!(
                        "{}: {} values for dimensions {}",
                        at("imaginary part"),
                        imag.len(),
                        dims_text(&dims)
                    ));
                }
                Some(imag)
            } else {
                None
            };
            MatValue::Numeric(NumericArray { dims, real, imag })
        }
        MatClass::Char => {
            let (ty, raw) = r.element().map_err(|e| format!("{}: {e}", at("text")))?;
            let units: Vec<u16> = if ty == MI_UTF8 {
                let text = String::from_utf8_lossy(raw);
                text.encode_utf16().collect()
            } else {
                match decode(ty, raw, little).map_err(|e| format!("{}: {e}", at("text")))? {
                    Stored::Ints(v) => v.into_iter().map(|c| c as u16).collect(),
                    _ => {
                        return Err(format!("{}: characters stored as floating point", at("text")));
                    }
                }
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
            let name_len = match decode(ty, len_raw, little)? {
                Stored::Ints(v) if v.len() == 1 && v[0] > 0 => v[0] as usize,
                _ => return Err(format!("{}: bad field name length", at("struct"))),
            };
            let (_, names_raw) = r.element().map_err(|e| format!("{}: {e}", at("field names")))?;
            let field_names: Vec<String> = names_raw
                .chunks(name_len)
                .map(|c| String::from_utf8_lossy(c).trim_end_matches('\0').to_string())
                .collect();
            let mut elements = Vec::with_capacity(count);
            for _ in 0..count {
                let mut values = Vec::with_capacity(field_names.len());
                for f in &field_names {
                    let (ty, sub) = r.element().map_err(|e| format!("'{name}.{f}': {e}"))?;
                    if ty != MI_MATRIX {
                        return Err(format!("'{name}.{f}': field is not an array element"));
                    }
                    let (_, v) = parse_matrix(sub, little, depth + 1)
                        .map_err(|e| format!("'{name}.{f}': {e}"))?;
                    values.push(v);
                }
                elements.push(values);
            }
            MatValue::Struct(StructArray { dims, field_names, elements })
        }
        MatClass::Cell => {
            let mut cells = Vec::with_capacity(count);
            for i in 0..count {
                let (ty, sub) = r.element().map_err(|e| format!("'{name}{{{}}}': {e}", i + 1))?;
                if ty != MI_MATRIX {
                    return Err(format!("'{name}{{{}}}': cell is not an array element", i + 1));
                }
                let (_, v) = parse_matrix(sub, little, depth + 1)
                    .map_err(|e| format!("'{name}{{{}}}': {e}", i + 1))?;
                cells.push(v);
            }
            MatValue::Cell { dims, cells }
        }
        other => MatValue::Unsupported { class: other },
    };
    Ok((name, value))
}
