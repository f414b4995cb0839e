//! Stage 2 of the reader: the values of one numeric data element, decoded from its stored type
//! (`miINT8` … `miDOUBLE`, either byte order) and converted to the array's MATLAB class.
//!
//! Values go straight from the stored bytes into the class's type (one pass, no wider
//! intermediate array), so an element never takes more memory than its bytes times the
//! widening from storage to class (at most 8×: MATLAB stores integer-valued doubles as
//! `uint8`). Integers pass through `i128` and floats through `f64` one value at a time, which
//! is exact for every pair of types.

use super::header::*;
use super::value::{MatClass, NumericData};

/// A primitive type a data element can be stored as.
trait StoredValue: Copy {
    const SIZE: usize;
    fn read(bytes: &[u8], little: bool) -> Self;
}

macro_rules! stored_value {
    ($($t:ty),*) => {$(
        impl StoredValue for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            fn read(bytes: &[u8], little: bool) -> Self {
                let arr: [u8; std::mem::size_of::<$t>()] =
                    bytes.try_into().unwrap_or([0; std::mem::size_of::<$t>()]);
                if little { <$t>::from_le_bytes(arr) } else { <$t>::from_be_bytes(arr) }
            }
        }
    )*};
}
stored_value!(i8, u8, i16, u16, i32, u32, i64, u64, f32, f64);

fn each<S: StoredValue, T>(
    data: &[u8],
    little: bool,
    f: impl Fn(S) -> T,
) -> Result<Vec<T>, String> {
    if !data.len().is_multiple_of(S::SIZE) {
        return Err(format!(
            "data of {} bytes is not a whole number of {}-byte values",
            data.len(),
            S::SIZE
        ));
    }
    Ok(data.chunks_exact(S::SIZE).map(|c| f(S::read(c, little))).collect())
}

/// Bytes per value of stored type `ty`, `None` for types that hold no numbers.
pub(super) fn stored_size(ty: u32) -> Option<usize> {
    Some(match ty {
        MI_INT8 | MI_UINT8 | MI_UTF8 => 1,
        MI_INT16 | MI_UINT16 | MI_UTF16 => 2,
        MI_INT32 | MI_UINT32 | MI_UTF32 | MI_SINGLE => 4,
        MI_DOUBLE | MI_INT64 | MI_UINT64 => 8,
        _ => return None,
    })
}

/// Decodes every value of an element of stored type `ty`: integers through `from_int`,
/// floating-point values through `from_float`.
pub(super) fn decode_with<T>(
    ty: u32,
    data: &[u8],
    little: bool,
    from_int: impl Fn(i128) -> T,
    from_float: impl Fn(f64) -> T,
) -> Result<Vec<T>, String> {
    match ty {
        MI_INT8 => each(data, little, |v: i8| from_int(v as i128)),
        MI_UINT8 | MI_UTF8 => each(data, little, |v: u8| from_int(v as i128)),
        MI_INT16 => each(data, little, |v: i16| from_int(v as i128)),
        MI_UINT16 | MI_UTF16 => each(data, little, |v: u16| from_int(v as i128)),
        MI_INT32 => each(data, little, |v: i32| from_int(v as i128)),
        MI_UINT32 | MI_UTF32 => each(data, little, |v: u32| from_int(v as i128)),
        MI_INT64 => each(data, little, |v: i64| from_int(v as i128)),
        MI_UINT64 => each(data, little, |v: u64| from_int(v as i128)),
        MI_SINGLE => each(data, little, |v: f32| from_float(v as f64)),
        MI_DOUBLE => each(data, little, from_float),
        other => Err(format!("unknown data type {other} in a numeric element")),
    }
}

/// Decodes an element that must hold integers (dimensions, lengths, character codes).
pub(super) fn decode_ints(ty: u32, data: &[u8], little: bool) -> Result<Vec<i128>, String> {
    if matches!(ty, MI_SINGLE | MI_DOUBLE) {
        return Err("integers stored as floating point".into());
    }
    decode_with(ty, data, little, |x| x, |x| x as i128)
}

/// Decodes a numeric element into the array's class (`logical` arrays are `uint8` 0/1).
pub(super) fn read_numeric(
    ty: u32,
    data: &[u8],
    little: bool,
    class: MatClass,
    logical: bool,
) -> Result<NumericData, String> {
    macro_rules! to {
        ($variant:ident, $t:ty) => {
            NumericData::$variant(decode_with(ty, data, little, |x| x as $t, |x| x as $t)?)
        };
    }
    if logical {
        return Ok(to!(Logical, u8));
    }
    Ok(match class {
        MatClass::Double => to!(Double, f64),
        MatClass::Single => to!(Single, f32),
        MatClass::Int8 => to!(Int8, i8),
        MatClass::UInt8 | MatClass::Logical => to!(UInt8, u8),
        MatClass::Int16 => to!(Int16, i16),
        MatClass::UInt16 => to!(UInt16, u16),
        MatClass::Int32 => to!(Int32, i32),
        MatClass::UInt32 => to!(UInt32, u32),
        MatClass::Int64 => to!(Int64, i64),
        MatClass::UInt64 => to!(UInt64, u64),
        other => return Err(format!("class {} is not numeric", other.name())),
    })
}

/// Bytes one value of a numeric class takes in memory.
pub(super) fn class_size(class: MatClass, logical: bool) -> usize {
    match class {
        _ if logical => 1,
        MatClass::Double | MatClass::Int64 | MatClass::UInt64 => 8,
        MatClass::Single | MatClass::Int32 | MatClass::UInt32 => 4,
        MatClass::Int16 | MatClass::UInt16 => 2,
        _ => 1,
    }
}
