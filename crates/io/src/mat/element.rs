//! Stage 2 of the reader: the values of one numeric data element, decoded from its stored type
//! (`miINT8` … `miDOUBLE`, either byte order) and converted to the array's MATLAB class.

use super::header::*;
use super::value::{MatClass, NumericData};

/// Values of one stored data element, before conversion to the array's class.
pub(super) enum Stored {
    Ints(Vec<i128>),
    Floats(Vec<f64>),
}

#[allow(clippy::modulo_one)] // the macro also serves 1-byte types
pub(super) fn decode(ty: u32, data: &[u8], little: bool) -> Result<Stored, String> {
    macro_rules! ints {
        ($t:ty, $n:expr) => {{
            if data.len() % $n != 0 {
                return Err(format!(
                    "data of {} bytes is not a whole number of {}-byte values",
                    data.len(),
                    $n
                ));
            }
            Stored::Ints(
                data.chunks_exact($n)
                    .map(|c| {
                        let arr: [u8; $n] = c.try_into().unwrap_or([0; $n]);
                        (if little { <$t>::from_le_bytes(arr) } else { <$t>::from_be_bytes(arr) })
                            as i128
                    })
                    .collect(),
            )
        }};
    }
    Ok(match ty {
        MI_INT8 => ints!(i8, 1),
        MI_UINT8 | MI_UTF8 => ints!(u8, 1),
        MI_INT16 => ints!(i16, 2),
        MI_UINT16 | MI_UTF16 => ints!(u16, 2),
        MI_INT32 => ints!(i32, 4),
        MI_UINT32 | MI_UTF32 => ints!(u32, 4),
        MI_INT64 => ints!(i64, 8),
        MI_UINT64 => ints!(u64, 8),
        MI_SINGLE => {
            if !data.len().is_multiple_of(4) {
                return Err("single data is not a whole number of 4-byte values".into());
            }
            Stored::Floats(
                data.chunks_exact(4)
                    .map(|c| {
                        let arr = [c[0], c[1], c[2], c[3]];
                        (if little { f32::from_le_bytes(arr) } else { f32::from_be_bytes(arr) })
                            as f64
                    })
                    .collect(),
            )
        }
        MI_DOUBLE => {
            if !data.len().is_multiple_of(8) {
                return Err("double data is not a whole number of 8-byte values".into());
            }
            Stored::Floats(
                data.chunks_exact(8)
                    .map(|c| {
                        let arr: [u8; 8] = c.try_into().unwrap_or([0; 8]);
                        if little { f64::from_le_bytes(arr) } else { f64::from_be_bytes(arr) }
                    })
                    .collect(),
            )
        }
        other => return Err(format!("unknown data type {other} in a numeric element")),
    })
}

pub(super) fn convert(
    stored: Stored,
    class: MatClass,
    logical: bool,
) -> Result<NumericData, String> {
    macro_rules! conv {
        ($variant:ident, $t:ty) => {
            NumericData::$variant(match stored {
                Stored::Ints(v) => v.into_iter().map(|x| x as $t).collect(),
                Stored::Floats(v) => v.into_iter().map(|x| x as $t).collect(),
            })
        };
    }
    if logical {
        return Ok(conv!(Logical, u8));
    }
    Ok(match class {
        MatClass::Double => conv!(Double, f64),
        MatClass::Single => conv!(Single, f32),
        MatClass::Int8 => conv!(Int8, i8),
        MatClass::UInt8 | MatClass::Logical => conv!(UInt8, u8),
        MatClass::Int16 => conv!(Int16, i16),
        MatClass::UInt16 => conv!(UInt16, u16),
        MatClass::Int32 => conv!(Int32, i32),
        MatClass::UInt32 => conv!(UInt32, u32),
        MatClass::Int64 => conv!(Int64, i64),
        MatClass::UInt64 => conv!(UInt64, u64),
        other => return Err(format!("class {} is not numeric", other.name())),
    })
}
