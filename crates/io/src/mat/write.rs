//! The writer: uncompressed little-endian v5 files, enough for test inputs and small exports.

use std::path::Path;

use super::GeometryError;
use super::header::*;
use super::value::{MatClass, MatValue, NumericData};
use crate::atomic::write_bytes_atomic;

// ---------------------------------------------------------------------------------------
// Writing (uncompressed, little-endian): enough to produce test inputs and small exports.

fn push_element(out: &mut Vec<u8>, ty: u32, data: &[u8]) {
    out.extend_from_slice(&ty.to_le_bytes());
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out.extend_from_slice(data);
    while !out.len().is_multiple_of(8) {
        out.push(0);
    }
}

fn numeric_bytes(data: &NumericData) -> (u32, Vec<u8>) {
    macro_rules! bytes {
        ($ty:expr, $v:expr) => {
            ($ty, $v.iter().flat_map(|x| x.to_le_bytes()).collect())
        };
    }
    match data {
        NumericData::Double(v) => bytes!(MI_DOUBLE, v),
        NumericData::Single(v) => bytes!(MI_SINGLE, v),
        NumericData::Int8(v) => bytes!(MI_INT8, v),
        NumericData::UInt8(v) | NumericData::Logical(v) => bytes!(MI_UINT8, v),
        NumericData::Int16(v) => bytes!(MI_INT16, v),
        NumericData::UInt16(v) => bytes!(MI_UINT16, v),
        NumericData::Int32(v) => bytes!(MI_INT32, v),
        NumericData::UInt32(v) => bytes!(MI_UINT32, v),
        NumericData::Int64(v) => bytes!(MI_INT64, v),
        NumericData::UInt64(v) => bytes!(MI_UINT64, v),
    }
}

fn matrix_bytes(name: &str, value: &MatValue) -> Result<Vec<u8>, String> {
    let mut body = Vec::new();
    let (class, complex, logical) = match value {
        MatValue::Numeric(a) => (a.class(), a.is_complex(), a.class() == MatClass::Logical),
        MatValue::Unsupported { class } => {
            return Err(format!("cannot write a {} value ('{name}')", class.name()));
        }
        other => (other.class(), false, false),
    };
    let flags =
        class.code() as u32 | if complex { 0x800 } else { 0 } | if logical { 0x200 } else { 0 };
    let mut flag_bytes = flags.to_le_bytes().to_vec();
    flag_bytes.extend_from_slice(&[0; 4]);
    push_element(&mut body, MI_UINT32, &flag_bytes);
    let dims: Vec<u8> = value.dims().iter().flat_map(|&d| (d as i32).to_le_bytes()).collect();
    push_element(&mut body, MI_INT32, &dims);
    push_element(&mut body, MI_INT8, name.as_bytes());
    match value {
        MatValue::Numeric(a) => {
            let (ty, b) = numeric_bytes(&a.real);
            push_element(&mut body, ty, &b);
            if let Some(im) = &a.imag {
                let (ty, b) = numeric_bytes(im);
                push_element(&mut body, ty, &b);
            }
        }
        MatValue::Char { units, .. } => {
            let b: Vec<u8> = units.iter().flat_map(|u| u.to_le_bytes()).collect();
            push_element(&mut body, MI_UINT16, &b);
        }
        MatValue::Struct(s) => {
            // Field names: fixed-length, NUL-terminated; MATLAB limits them to 63 characters.
            let len = s.field_names.iter().map(|f| f.len() + 1).max().unwrap_or(1).max(8);
            push_element(&mut body, MI_INT32, &(len as i32).to_le_bytes());
            let mut names = Vec::new();
            for f in &s.field_names {
                let mut b = f.as_bytes().to_vec();
                b.resize(len, 0);
                names.extend_from_slice(&b);
            }
            push_element(&mut body, MI_INT8, &names);
            for element in &s.elements {
                for v in element {
                    push_element(&mut body, MI_MATRIX, &matrix_bytes("", v)?);
                }
            }
        }
        MatValue::Cell { cells, .. } => {
            for v in cells {
                push_element(&mut body, MI_MATRIX, &matrix_bytes("", v)?);
            }
        }
        MatValue::Unsupported { .. } => {}
    }
    Ok(body)
}

/// Encodes variables as the bytes of an uncompressed little-endian v5 `.mat` file.
pub fn encode(variables: &[(&str, MatValue)]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut text = b"MATLAB 5.0 MAT-file, written by kfuse".to_vec();
    text.resize(116, b' ');
    out.extend_from_slice(&text);
    out.extend_from_slice(&[0; 8]); // no subsystem data
    out.extend_from_slice(&0x0100u16.to_le_bytes());
    out.extend_from_slice(b"IM");
    for (name, value) in variables {
        let body = matrix_bytes(name, value)?;
        push_element(&mut out, MI_MATRIX, &body);
    }
    Ok(out)
}

/// Writes variables to `path` as an uncompressed v5 `.mat` file (atomically).
pub fn write_mat(path: &Path, variables: &[(&str, MatValue)]) -> Result<(), GeometryError> {
    let bytes = encode(variables)
        .map_err(|message| GeometryError::Format { path: path.to_path_buf(), message })?;
    write_bytes_atomic(path, &bytes)
}
