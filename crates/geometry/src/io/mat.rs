//! MATLAB v5 `.mat` files (the format of `save` up to `-v7`; not the HDF5-based `-v7.3`).
//!
//! Reads every variable of a file into a [`MatValue`] tree: numeric arrays of every class
//! (double, single, int8…int64, uint8…uint64, logical; complex kept as a separate imaginary
//! part), char arrays, structs (nested, and struct arrays), and cell arrays. Compressed
//! elements (`miCOMPRESSED`, the default since MATLAB 7) are inflated with `flate2`. Sparse,
//! object and function-handle variables are kept as [`MatValue::Unsupported`] so that the rest
//! of the file stays readable; asking for them as numbers gives an error saying why.
//!
//! # Layout conventions
//!
//! MATLAB stores arrays **column-major** (first index fastest) with **1-based** indices. The
//! raw data of a [`NumericArray`] keeps that order; [`NumericArray::row_major_f64`] and
//! [`NumericArray::matrix`] convert to the row-major order used everywhere else in kfuse (last
//! index fastest: an `H×W×3` image becomes `[(y·W + x)·3 + c]`). Index *values* stored in a
//! file (e.g. a principal point) are not changed here: importers that know the file's meaning
//! convert them (see [`crate::io::course`]).
//!
//! MATLAB itself saves small integer-valued doubles with a narrower storage type (a `cx` of
//! 320 may be stored as `uint16`); the reader converts the stored values back to the array's
//! class, so `class` is what MATLAB would show.
//!
//! # Why our own reader
//!
//! The `matfile` crate (0.5) reads numeric arrays only and silently drops structs and char
//! arrays, which hold the parameters of every file we import (`Dparam`, `Cparam`,
//! `calib_name`…). The v5 format is small and fully documented (MathWorks, "MAT-File Format",
//! 2024), so a ~500-line reader with exact errors is cheaper than a dependency that cannot
//! read our files.
//!
//! ```no_run
//! use geometry::io::mat::MatFile;
//! let file = MatFile::read("Calib_Results_left.mat".as_ref())?;
//! let fc = file.matrix("fc")?; // 2×1
//! let fx = fc.data[0];
//! let cx = file.scalar("Cparam.cx").ok(); // struct field, dotted path
//! # Ok::<(), geometry::GeometryError>(())
//! ```

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::GeometryError;
use crate::io::atomic::write_bytes_atomic;

/// Size of the text + subsystem + version + endian header of every v5 file.
const HEADER_LEN: usize = 128;
/// Largest number of dimensions accepted; MATLAB arrays rarely exceed 4, 32 guards against
/// garbage tags describing absurd shapes.
const MAX_DIMS: usize = 32;
/// Deepest nesting of structs / cells accepted (protects the stack from crafted files).
const MAX_DEPTH: usize = 64;

// Data types of data elements (MAT-File Format, table 1-1).
const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
const MI_UTF8: u32 = 16;
const MI_UTF16: u32 = 17;
const MI_UTF32: u32 = 18;

/// The MATLAB class of an array (what `class(x)` prints).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MatClass {
    /// `cell`.
    Cell,
    /// `struct`.
    Struct,
    /// An object (not supported).
    Object,
    /// `char`.
    Char,
    /// A sparse matrix (not supported).
    Sparse,
    /// `double`.
    Double,
    /// `single`.
    Single,
    /// `int8`.
    Int8,
    /// `uint8`.
    UInt8,
    /// `int16`.
    Int16,
    /// `uint16`.
    UInt16,
    /// `int32`.
    Int32,
    /// `uint32`.
    UInt32,
    /// `int64`.
    Int64,
    /// `uint64`.
    UInt64,
    /// `logical` (stored as a `uint8` array with the logical flag).
    Logical,
    /// Function handles, opaque classes and anything newer (not supported).
    Other(u8),
}

impl MatClass {
    fn from_code(code: u8) -> Self {
        match code {
            1 => MatClass::Cell,
            2 => MatClass::Struct,
            3 => MatClass::Object,
            4 => MatClass::Char,
            5 => MatClass::Sparse,
            6 => MatClass::Double,
            7 => MatClass::Single,
            8 => MatClass::Int8,
            9 => MatClass::UInt8,
            10 => MatClass::Int16,
            11 => MatClass::UInt16,
            12 => MatClass::Int32,
            13 => MatClass::UInt32,
            14 => MatClass::Int64,
            15 => MatClass::UInt64,
            other => MatClass::Other(other),
        }
    }

    fn code(self) -> u8 {
        match self {
            MatClass::Cell => 1,
            MatClass::Struct => 2,
            MatClass::Object => 3,
            MatClass::Char => 4,
            MatClass::Sparse => 5,
            MatClass::Double => 6,
            MatClass::Single => 7,
            MatClass::Int8 => 8,
            MatClass::UInt8 | MatClass::Logical => 9,
            MatClass::Int16 => 10,
            MatClass::UInt16 => 11,
            MatClass::Int32 => 12,
            MatClass::UInt32 => 13,
            MatClass::Int64 => 14,
            MatClass::UInt64 => 15,
            MatClass::Other(c) => c,
        }
    }

    /// MATLAB's name of the class.
    pub fn name(self) -> &'static str {
        match self {
            MatClass::Cell => "cell",
            MatClass::Struct => "struct",
            MatClass::Object => "object",
            MatClass::Char => "char",
            MatClass::Sparse => "sparse",
            MatClass::Double => "double",
            MatClass::Single => "single",
            MatClass::Int8 => "int8",
            MatClass::UInt8 => "uint8",
            MatClass::Int16 => "int16",
            MatClass::UInt16 => "uint16",
            MatClass::Int32 => "int32",
            MatClass::UInt32 => "uint32",
            MatClass::Int64 => "int64",
            MatClass::UInt64 => "uint64",
            MatClass::Logical => "logical",
            MatClass::Other(_) => "unsupported class",
        }
    }
}

/// The values of a numeric array in its class's type, column-major.
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)] // one variant per MATLAB class, named after it
pub enum NumericData {
    Double(Vec<f64>),
    Single(Vec<f32>),
    Int8(Vec<i8>),
    UInt8(Vec<u8>),
    Int16(Vec<i16>),
    UInt16(Vec<u16>),
    Int32(Vec<i32>),
    UInt32(Vec<u32>),
    Int64(Vec<i64>),
    UInt64(Vec<u64>),
    /// `logical`: 0 or 1.
    Logical(Vec<u8>),
}

macro_rules! for_each_numeric {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            NumericData::Double($v) => $body,
            NumericData::Single($v) => $body,
            NumericData::Int8($v) => $body,
            NumericData::UInt8($v) => $body,
            NumericData::Int16($v) => $body,
            NumericData::UInt16($v) => $body,
            NumericData::Int32($v) => $body,
            NumericData::UInt32($v) => $body,
            NumericData::Int64($v) => $body,
            NumericData::UInt64($v) => $body,
            NumericData::Logical($v) => $body,
        }
    };
}

#[allow(clippy::unnecessary_cast)] // the macro also serves the f64 / f32 variants
impl NumericData {
    /// Number of values.
    pub fn len(&self) -> usize {
        for_each_numeric!(self, v => v.len())
    }

    /// True when there is no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The class these values belong to.
    pub fn class(&self) -> MatClass {
        match self {
            NumericData::Double(_) => MatClass::Double,
            NumericData::Single(_) => MatClass::Single,
            NumericData::Int8(_) => MatClass::Int8,
            NumericData::UInt8(_) => MatClass::UInt8,
            NumericData::Int16(_) => MatClass::Int16,
            NumericData::UInt16(_) => MatClass::UInt16,
            NumericData::Int32(_) => MatClass::Int32,
            NumericData::UInt32(_) => MatClass::UInt32,
            NumericData::Int64(_) => MatClass::Int64,
            NumericData::UInt64(_) => MatClass::UInt64,
            NumericData::Logical(_) => MatClass::Logical,
        }
    }

    /// Value `i` (column-major index) as `f64`. 64-bit integers beyond 2⁵³ round.
    pub fn get_f64(&self, i: usize) -> Option<f64> {
        for_each_numeric!(self, v => v.get(i).map(|&x| x as f64))
    }

    /// Every value as `f64`, column-major. 64-bit integers beyond 2⁵³ round.
    pub fn to_f64(&self) -> Vec<f64> {
        for_each_numeric!(self, v => v.iter().map(|&x| x as f64).collect())
    }

    /// Every value as `f32`, column-major (doubles round to the nearest `f32`).
    pub fn to_f32(&self) -> Vec<f32> {
        for_each_numeric!(self, v => v.iter().map(|&x| x as f32).collect())
    }
}

/// A numeric (or logical) array.
#[derive(Debug, Clone, PartialEq)]
pub struct NumericArray {
    /// MATLAB dimensions (at least two: a scalar is `[1, 1]`).
    pub dims: Vec<usize>,
    /// Real part, column-major.
    pub real: NumericData,
    /// Imaginary part of a complex array, column-major.
    pub imag: Option<NumericData>,
}

/// A 2-D real matrix converted to `f64`, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct MatMatrix {
    /// Number of rows.
    pub rows: usize,
    /// Number of columns.
    pub cols: usize,
    /// `rows * cols` values, row-major: element `(r, c)` is `data[r * cols + c]`.
    pub data: Vec<f64>,
}

impl MatMatrix {
    /// Element at row `r`, column `c` (0-based).
    pub fn at(&self, r: usize, c: usize) -> f64 {
        self.data[r * self.cols + c]
    }
}

impl NumericArray {
    /// Number of elements (product of the dimensions).
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// True when the array has no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The array's class.
    pub fn class(&self) -> MatClass {
        self.real.class()
    }

    /// True for complex arrays.
    pub fn is_complex(&self) -> bool {
        self.imag.is_some()
    }

    /// The real part converted to `f64` in row-major order (last dimension fastest).
    pub fn row_major_f64(&self) -> Vec<f64> {
        column_to_row_major(&self.real.to_f64(), &self.dims)
    }

    /// The array as a real 2-D matrix (row-major `f64`); `Err` says why not (complex or more
    /// than two non-singleton dimensions).
    pub fn matrix(&self) -> Result<MatMatrix, String> {
        if self.is_complex() {
            return Err(format!(
                "is a complex {} array; kfuse needs real numbers",
                self.class().name()
            ));
        }
        if self.dims.len() > 2 && self.dims[2..].iter().any(|&d| d != 1) {
            return Err(format!(
                "has {} dimensions ({}); expected a 2-D matrix",
                self.dims.len(),
                dims_text(&self.dims)
            ));
        }
        let rows = self.dims.first().copied().unwrap_or(0);
        let cols = self.dims.get(1).copied().unwrap_or(1);
        Ok(MatMatrix { rows, cols, data: column_to_row_major(&self.real.to_f64(), &[rows, cols]) })
    }
}

/// Reorders column-major data of shape `dims` (MATLAB) into row-major order (C), i.e. the
/// element at MATLAB index `(i0, i1, …)` moves to position `((i0·d1 + i1)·d2 + …)`.
pub fn column_to_row_major<T: Copy>(data: &[T], dims: &[usize]) -> Vec<T> {
    let n: usize = dims.iter().product();
    if dims.len() < 2 || n != data.len() || n == 0 {
        return data.to_vec();
    }
    // Row-major strides of the destination.
    let mut dst_stride = vec![1usize; dims.len()];
    for k in (0..dims.len() - 1).rev() {
        dst_stride[k] = dst_stride[k + 1] * dims[k + 1];
    }
    let mut out = Vec::with_capacity(n);
    // Filled with the first value, then every slot is overwritten exactly once.
    out.resize(n, data[0]);
    let mut idx = vec![0usize; dims.len()];
    for &value in data {
        let dst: usize = idx.iter().zip(&dst_stride).map(|(i, s)| i * s).sum();
        out[dst] = value;
        // Advance the column-major multi-index (first dimension fastest).
        for (k, i) in idx.iter_mut().enumerate() {
            *i += 1;
            if *i < dims[k] {
                break;
            }
            *i = 0;
        }
    }
    out
}

/// Reorders row-major data of shape `dims` into MATLAB's column-major order (the inverse of
/// [`column_to_row_major`]).
pub fn row_to_column_major<T: Copy>(data: &[T], dims: &[usize]) -> Vec<T> {
    let n: usize = dims.iter().product();
    if dims.len() < 2 || n != data.len() || n == 0 {
        return data.to_vec();
    }
    let reversed: Vec<usize> = dims.iter().rev().copied().collect();
    // Row-major data of dims is column-major data of the reversed dims.
    column_to_row_major(data, &reversed)
}

fn dims_text(dims: &[usize]) -> String {
    dims.iter().map(|d| d.to_string()).collect::<Vec<_>>().join("×")
}

/// A struct or struct array.
#[derive(Debug, Clone, PartialEq)]
pub struct StructArray {
    /// Dimensions of the struct array (`[1, 1]` for a plain struct).
    pub dims: Vec<usize>,
    /// Field names in file order.
    pub field_names: Vec<String>,
    /// One entry per element (column-major), each holding one value per field in the order
    /// of `field_names`.
    pub elements: Vec<Vec<MatValue>>,
}

impl StructArray {
    /// Field `name` of element 0 (the only one of a plain struct).
    pub fn field(&self, name: &str) -> Option<&MatValue> {
        self.field_of(0, name)
    }

    /// Field `name` of element `index` (column-major).
    pub fn field_of(&self, index: usize, name: &str) -> Option<&MatValue> {
        let k = self.field_names.iter().position(|f| f == name)?;
        self.elements.get(index)?.get(k)
    }
}

/// One MATLAB value.
#[derive(Debug, Clone, PartialEq)]
pub enum MatValue {
    /// A numeric or logical array.
    Numeric(NumericArray),
    /// A char array: dimensions and UTF-16 code units, column-major.
    Char {
        /// Dimensions (`[1, n]` for a string).
        dims: Vec<usize>,
        /// Code units, column-major.
        units: Vec<u16>,
    },
    /// A struct or struct array.
    Struct(StructArray),
    /// A cell array: dimensions and cells, column-major.
    Cell {
        /// Dimensions.
        dims: Vec<usize>,
        /// Cells, column-major.
        cells: Vec<MatValue>,
    },
    /// A variable this reader does not decode (sparse, object, function handle…).
    Unsupported {
        /// Its class.
        class: MatClass,
    },
}

impl MatValue {
    /// A real double matrix from row-major data (for building files to write).
    pub fn double_matrix(rows: usize, cols: usize, row_major: &[f64]) -> MatValue {
        MatValue::Numeric(NumericArray {
            dims: vec![rows, cols],
            real: NumericData::Double(row_to_column_major(row_major, &[rows, cols])),
            imag: None,
        })
    }

    /// A 1×1 double.
    pub fn scalar(value: f64) -> MatValue {
        MatValue::double_matrix(1, 1, &[value])
    }

    /// A 1×n char array.
    pub fn string(text: &str) -> MatValue {
        let units: Vec<u16> = text.encode_utf16().collect();
        MatValue::Char { dims: vec![1, units.len()], units }
    }

    /// A 1×1 struct with the given fields.
    pub fn structure(fields: Vec<(&str, MatValue)>) -> MatValue {
        let field_names = fields.iter().map(|(n, _)| n.to_string()).collect();
        let values = fields.into_iter().map(|(_, v)| v).collect();
        MatValue::Struct(StructArray { dims: vec![1, 1], field_names, elements: vec![values] })
    }

    /// The value's class.
    pub fn class(&self) -> MatClass {
        match self {
            MatValue::Numeric(a) => a.class(),
            MatValue::Char { .. } => MatClass::Char,
            MatValue::Struct(_) => MatClass::Struct,
            MatValue::Cell { .. } => MatClass::Cell,
            MatValue::Unsupported { class } => *class,
        }
    }

    /// Dimensions.
    pub fn dims(&self) -> &[usize] {
        match self {
            MatValue::Numeric(a) => &a.dims,
            MatValue::Char { dims, .. } | MatValue::Cell { dims, .. } => dims,
            MatValue::Struct(s) => &s.dims,
            MatValue::Unsupported { .. } => &[],
        }
    }

    /// The numeric array, if this is one.
    pub fn as_numeric(&self) -> Option<&NumericArray> {
        match self {
            MatValue::Numeric(a) => Some(a),
            _ => None,
        }
    }

    /// The struct, if this is one.
    pub fn as_struct(&self) -> Option<&StructArray> {
        match self {
            MatValue::Struct(s) => Some(s),
            _ => None,
        }
    }

    /// The cells of a cell array.
    pub fn as_cells(&self) -> Option<&[MatValue]> {
        match self {
            MatValue::Cell { cells, .. } => Some(cells),
            _ => None,
        }
    }

    /// Field `name` of a (1×1) struct.
    pub fn field(&self, name: &str) -> Option<&MatValue> {
        self.as_struct()?.field(name)
    }

    /// A char array as text; multi-row char arrays give their rows joined by `\n`.
    pub fn as_string(&self) -> Option<String> {
        match self {
            MatValue::Char { dims, units } => {
                let rows = dims.first().copied().unwrap_or(0);
                if rows <= 1 {
                    return Some(String::from_utf16_lossy(units));
                }
                let row_major = column_to_row_major(units, &[rows, units.len() / rows]);
                let lines: Vec<String> =
                    row_major.chunks(units.len() / rows).map(String::from_utf16_lossy).collect();
                Some(lines.join("\n"))
            }
            _ => None,
        }
    }

    /// A real numeric 2-D array as a row-major `f64` matrix; `Err` says why not.
    pub fn as_f64_matrix(&self) -> Result<MatMatrix, String> {
        match self {
            MatValue::Numeric(a) => a.matrix(),
            other => Err(format!("is a {} value, expected a numeric matrix", describe(other))),
        }
    }

    /// A real numeric value with exactly one element.
    pub fn as_scalar(&self) -> Result<f64, String> {
        let m = self.as_f64_matrix()?;
        if m.data.len() != 1 {
            return Err(format!("is a {}×{} matrix, expected a scalar", m.rows, m.cols));
        }
        Ok(m.data[0])
    }
}

fn describe(v: &MatValue) -> String {
    match v {
        MatValue::Unsupported { class } => match class {
            MatClass::Sparse => "sparse (not supported: convert with full() in MATLAB)".into(),
            MatClass::Object => "object (not supported: save its fields as a struct)".into(),
            MatClass::Other(c) => {
                format!("class-{c} (function handle or opaque object, not supported)")
            }
            c => c.name().into(),
        },
        other => format!("{} {}", dims_text(other.dims()), other.class().name()),
    }
}

/// A parsed `.mat` file: its variables in file order.
#[derive(Debug, Clone)]
pub struct MatFile {
    path: PathBuf,
    header: String,
    variables: Vec<(String, MatValue)>,
}

impl MatFile {
    /// Reads and parses the file at `path`.
    pub fn read(path: &Path) -> Result<Self, GeometryError> {
        let bytes = std::fs::read(path)
            .map_err(|source| GeometryError::Io { path: path.to_path_buf(), source })?;
        Self::parse(&bytes, path)
    }

    /// Parses the bytes of a file; `path` is used in error messages only.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self, GeometryError> {
        let fail = |message: String| GeometryError::Format { path: path.to_path_buf(), message };
        if bytes.len() < HEADER_LEN {
            return Err(fail(format!(
                "not a MATLAB v5 .mat file: {} bytes, shorter than the 128-byte header",
                bytes.len()
            )));
        }
        if bytes.starts_with(b"\x89HDF")
            || bytes[..HEADER_LEN.min(bytes.len())].windows(4).any(|w| w == b"HDF5")
        {
            return Err(fail(
                "is a MATLAB v7.3 (HDF5) file, which is not supported: re-save it in MATLAB with save(..., '-v7')".into(),
            ));
        }
        let header =
            String::from_utf8_lossy(&bytes[..116]).trim_end_matches([' ', '\0']).to_string();
        let little = match &bytes[126..128] {
            b"IM" => true,
            b"MI" => false,
            _ => {
                return Err(fail(format!(
                    "not a MATLAB v5 .mat file (header says '{}'); expected the 'MATLAB 5.0 MAT-file' header",
                    header.chars().take(40).collect::<String>()
                )));
            }
        };
        if !header.starts_with("MATLAB") {
            return Err(fail(
                "not a MATLAB v5 .mat file: header does not start with 'MATLAB'".into(),
            ));
        }
        let mut reader = Reader { bytes, pos: HEADER_LEN, little };
        let mut variables = Vec::new();
        while reader.pos < bytes.len() {
            // Trailing zero padding after the last element is legal.
            if bytes[reader.pos..].iter().all(|&b| b == 0) {
                break;
            }
            let at = reader.pos;
            let (ty, data) = reader.element().map_err(|e| {
                fail(format!("variable #{} at byte {at}: {e}", variables.len() + 1))
            })?;
            let inflated;
            let (ty2, payload): (u32, &[u8]) = if ty == MI_COMPRESSED {
                let mut out = Vec::new();
                flate2::read::ZlibDecoder::new(data).read_to_end(&mut out).map_err(|e| {
                    fail(format!(
                        "variable #{} at byte {at}: compressed data is corrupt or truncated ({e})",
                        variables.len() + 1
                    ))
                })?;
                inflated = out;
                let mut inner = Reader { bytes: &inflated, pos: 0, little };
                inner.element().map_err(|e| {
                    fail(format!("variable #{} at byte {at} (inflated): {e}", variables.len() + 1))
                })?
            } else {
                (ty, data)
            };
            if ty2 != MI_MATRIX {
                // Not a variable (e.g. subsystem data): skip.
                continue;
            }
            let (name, value) = parse_matrix(payload, little, 0).map_err(|e| {
                fail(format!("variable #{} at byte {at}: {e}", variables.len() + 1))
            })?;
            variables.push((name, value));
        }
        Ok(Self { path: path.to_path_buf(), header, variables })
    }

    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The 116-byte descriptive header text ("MATLAB 5.0 MAT-file, Platform: …").
    pub fn header(&self) -> &str {
        &self.header
    }

    /// Variable names in file order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.variables.iter().map(|(n, _)| n.as_str())
    }

    /// The variable `name`, if present.
    pub fn get(&self, name: &str) -> Option<&MatValue> {
        self.variables.iter().find(|(n, _)| n == name).map(|(_, v)| v)
    }

    /// The value at a dotted path: `"R"`, `"Dparam.fx"`, `"a.b.c"` (struct fields of 1×1
    /// structs). The error names the file and the part of the path that is missing.
    pub fn require(&self, path: &str) -> Result<&MatValue, GeometryError> {
        let mut parts = path.split('.');
        let first = parts.next().unwrap_or_default();
        let mut value = self.get(first).ok_or_else(|| {
            let names: Vec<&str> = self.names().collect();
            self.error(format!(
                "has no variable '{first}' (needed: '{path}'); it holds: {}",
                if names.is_empty() { "no variables".to_string() } else { names.join(", ") }
            ))
        })?;
        let mut walked = first.to_string();
        for part in parts {
            let s = value.as_struct().ok_or_else(|| {
                self.error(format!(
                    "variable '{walked}' is a {}, not a struct (needed: '{path}')",
                    describe(value)
                ))
            })?;
            value = s.field(part).ok_or_else(|| {
                self.error(format!(
                    "struct '{walked}' has no field '{part}' (needed: '{path}'); its fields: {}",
                    s.field_names.join(", ")
                ))
            })?;
            walked.push('.');
            walked.push_str(part);
        }
        Ok(value)
    }

    /// The real 2-D matrix at `path` (see [`MatFile::require`]), row-major `f64`.
    pub fn matrix(&self, path: &str) -> Result<MatMatrix, GeometryError> {
        self.require(path)?
            .as_f64_matrix()
            .map_err(|why| self.error(format!("variable '{path}' {why}")))
    }

    /// The real matrix at `path`, which must be `rows × cols`.
    pub fn matrix_of_size(
        &self,
        path: &str,
        rows: usize,
        cols: usize,
    ) -> Result<MatMatrix, GeometryError> {
        let m = self.matrix(path)?;
        if m.rows != rows || m.cols != cols {
            return Err(self.error(format!(
                "variable '{path}' is {}×{}, expected {rows}×{cols}",
                m.rows, m.cols
            )));
        }
        Ok(m)
    }

    /// The real scalar at `path`.
    pub fn scalar(&self, path: &str) -> Result<f64, GeometryError> {
        self.require(path)?
            .as_scalar()
            .map_err(|why| self.error(format!("variable '{path}' {why}")))
    }

    /// The char array at `path` as text.
    pub fn string(&self, path: &str) -> Result<String, GeometryError> {
        let v = self.require(path)?;
        v.as_string().ok_or_else(|| {
            self.error(format!("variable '{path}' is a {}, expected text", describe(v)))
        })
    }

    /// The numeric array at `path`.
    pub fn numeric(&self, path: &str) -> Result<&NumericArray, GeometryError> {
        let v = self.require(path)?;
        v.as_numeric().ok_or_else(|| {
            self.error(format!("variable '{path}' is a {}, expected a numeric array", describe(v)))
        })
    }

    /// A format error naming this file.
    pub fn error(&self, message: String) -> GeometryError {
        GeometryError::Format { path: self.path.clone(), message }
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    little: bool,
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
    fn element(&mut self) -> Result<(u32, &'a [u8]), String> {
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

/// Values of one stored data element, before conversion to the array's class.
enum Stored {
    Ints(Vec<i128>),
    Floats(Vec<f64>),
}

#[allow(clippy::modulo_one)] // the macro also serves 1-byte types
fn decode(ty: u32, data: &[u8], little: bool) -> Result<Stored, String> {
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

fn convert(stored: Stored, class: MatClass, logical: bool) -> Result<NumericData, String> {
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

/// Parses the content of an `miMATRIX` element into `(name, value)`.
fn parse_matrix(data: &[u8], little: bool, depth: usize) -> Result<(String, MatValue), String> {
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

fn r_u32(b: &[u8], little: bool) -> u32 {
    let arr = [b[0], b[1], b[2], b[3]];
    if little { u32::from_le_bytes(arr) } else { u32::from_be_bytes(arr) }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_major_to_row_major_3d() {
        // MATLAB A(i,j,k) with dims 2×3×2, column-major value = i + 10 j + 100 k.
        let dims = [2, 3, 2];
        let mut col = Vec::new();
        for k in 0..2 {
            for j in 0..3 {
                for i in 0..2 {
                    col.push(i + 10 * j + 100 * k);
                }
            }
        }
        let row = column_to_row_major(&col, &dims);
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..2 {
                    assert_eq!(row[(i * 3 + j) * 2 + k], i + 10 * j + 100 * k);
                }
            }
        }
        assert_eq!(row_to_column_major(&row, &dims), col);
    }

    #[test]
    fn writer_round_trip_all_kinds() {
        let vars = vec![
            ("M", MatValue::double_matrix(2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
            (
                "s",
                MatValue::structure(vec![
                    ("name", MatValue::string("ir_")),
                    ("inner", MatValue::structure(vec![("x", MatValue::scalar(-2.5))])),
                ]),
            ),
            (
                "i16",
                MatValue::Numeric(NumericArray {
                    dims: vec![1, 3],
                    real: NumericData::Int16(vec![-7, 0, 300]),
                    imag: None,
                }),
            ),
            (
                "c",
                MatValue::Cell {
                    dims: vec![1, 2],
                    cells: vec![MatValue::scalar(1.0), MatValue::string("two")],
                },
            ),
        ];
        let bytes = encode(&vars).unwrap();
        let f = MatFile::parse(&bytes, Path::new("mem.mat")).unwrap();
        let m = f.matrix("M").unwrap();
        assert_eq!((m.rows, m.cols), (2, 3));
        assert_eq!(m.at(1, 0), 4.0);
        assert_eq!(f.string("s.name").unwrap(), "ir_");
        assert_eq!(f.scalar("s.inner.x").unwrap(), -2.5);
        assert_eq!(f.numeric("i16").unwrap().real, NumericData::Int16(vec![-7, 0, 300]));
        assert_eq!(f.require("c").unwrap().as_cells().unwrap()[1].as_string().unwrap(), "two");
        let err = f.scalar("s.missing").unwrap_err().to_string();
        assert!(
            err.contains("mem.mat")
                && err.contains("no field 'missing'")
                && err.contains("name, inner"),
            "{err}"
        );
        let err = f.matrix("nope").unwrap_err().to_string();
        assert!(err.contains("no variable 'nope'") && err.contains("M, s, i16, c"), "{err}");
    }

    #[test]
    fn complex_and_logical_arrays() {
        let vars = vec![
            (
                "z",
                MatValue::Numeric(NumericArray {
                    dims: vec![1, 2],
                    real: NumericData::Double(vec![1.0, 2.0]),
                    imag: Some(NumericData::Double(vec![0.5, -0.5])),
                }),
            ),
            (
                "mask",
                MatValue::Numeric(NumericArray {
                    dims: vec![2, 1],
                    real: NumericData::Logical(vec![1, 0]),
                    imag: None,
                }),
            ),
        ];
        let f = MatFile::parse(&encode(&vars).unwrap(), Path::new("c.mat")).unwrap();
        let z = f.numeric("z").unwrap();
        assert_eq!(z.imag, Some(NumericData::Double(vec![0.5, -0.5])));
        let err = f.matrix("z").unwrap_err().to_string();
        assert!(err.contains("c.mat") && err.contains("complex"), "{err}");
        assert_eq!(f.numeric("mask").unwrap().class(), MatClass::Logical);
        assert_eq!(f.matrix("mask").unwrap().data, vec![1.0, 0.0]);
    }

    #[test]
    fn truncated_and_garbage_files_give_errors_naming_the_file() {
        let bytes = encode(&[("M", MatValue::double_matrix(4, 4, &[1.0; 16]))]).unwrap();
        for cut in [10, 128 + 4, 128 + 40, bytes.len() - 9] {
            let err = MatFile::parse(&bytes[..cut], Path::new("cut.mat")).unwrap_err().to_string();
            assert!(err.starts_with("cut.mat:"), "{err}");
        }
        let err = MatFile::parse(&[b'x'; 300], Path::new("junk.mat")).unwrap_err().to_string();
        assert!(err.contains("junk.mat") && err.contains("not a MATLAB v5"), "{err}");
    }

    use crate::testdata::shared_data_or_skip as shared_data;

    #[test]
    fn bouguet_left_calibration_matches_its_readme() {
        let Some(data) = shared_data("bouguet_left_calibration_matches_its_readme") else { return };
        let f = MatFile::read(&data.join("kinect-lab/Calib_Results_left.mat")).unwrap();
        assert!(f.header().starts_with("MATLAB 5.0 MAT-file"));
        // README: "Bouguet's IR result (fx 364.126, fy 365.126)"; stated to 3 decimals.
        let fc = f.matrix_of_size("fc", 2, 1).unwrap();
        assert!(
            (fc.data[0] - 364.126).abs() < 5e-4 && (fc.data[1] - 365.126).abs() < 5e-4,
            "{fc:?}"
        );
        // Principal point fixed at ((w-1)/2, (h-1)/2) = (255.5, 211.5): exact in the file.
        let cc = f.matrix("cc").unwrap();
        assert_eq!(cc.data, vec![255.5, 211.5]);
        let kk = f.matrix_of_size("KK", 3, 3).unwrap();
        assert_eq!(
            (kk.at(0, 0), kk.at(0, 2), kk.at(1, 1), kk.at(2, 2)),
            (fc.data[0], 255.5, fc.data[1], 1.0)
        );
        // k3 fixed at 0 (README); stored as an integer-valued double.
        let kc = f.matrix_of_size("kc", 5, 1).unwrap();
        assert_eq!(kc.data[4], 0.0);
        assert_eq!(f.scalar("nx").unwrap(), 512.0);
        assert_eq!(f.scalar("ny").unwrap(), 424.0);
        assert_eq!(f.string("calib_name").unwrap(), "ir_");
        // Corners: 2×35, and README says 0-based pixels inside the 512×424 image.
        let x1 = f.matrix_of_size("x_1", 2, 35).unwrap();
        assert!(x1.data.iter().all(|v| (0.0..512.0).contains(v)));
        // Board points: 7×5 inner corners, 40 mm squares, x = 0..160 mm (README).
        let big_x = f.matrix_of_size("X_1", 3, 35).unwrap();
        assert_eq!(&big_x.data[..5], &[0.0, 40.0, 80.0, 120.0, 160.0]);
        assert!(f.names().count() > 200);
    }

    #[test]
    fn bouguet_stereo_and_kinect_data_read() {
        let Some(data) = shared_data("bouguet_stereo_and_kinect_data_read") else { return };
        let st = MatFile::read(&data.join("kinect-lab/Calib_Results_stereo.mat")).unwrap();
        // README: "stereo (T = (-52.195, -0.262, 0.625) mm)", stated to 3 decimals.
        let t = st.matrix_of_size("T", 3, 1).unwrap();
        for (got, want) in t.data.iter().zip([-52.195, -0.262, 0.625]) {
            assert!((got - want).abs() < 5e-4, "T = {:?}", t.data);
        }
        let r = st.matrix_of_size("R", 3, 3).unwrap();
        // R must be a rotation: rows orthonormal to rounding (1e-9 ≫ double round-off).
        for i in 0..3 {
            for j in 0..3 {
                let dot: f64 = (0..3).map(|k| r.at(i, k) * r.at(j, k)).sum();
                assert!((dot - if i == j { 1.0 } else { 0.0 }).abs() < 1e-9);
            }
        }
        let kd = MatFile::read(&data.join("kinect-lab/KinectData.mat")).unwrap();
        let img = kd.numeric("Image").unwrap();
        assert_eq!(img.dims, vec![1080, 1920, 3]);
        assert_eq!(img.class(), MatClass::UInt8);
        // The lab's stereo intrinsics are copied into Cparam/Dparam: same numbers as KK_*.
        let kk_right = st.matrix("KK_right").unwrap();
        assert_eq!(kd.scalar("Cparam.fx").unwrap(), kk_right.at(0, 0));
        assert_eq!(kd.scalar("Dparam.cx").unwrap(), 255.5);
        assert_eq!(kd.matrix("T").unwrap().data, t.data);
    }

    #[test]
    fn course_synthdata_reads_structs_and_single_arrays() {
        let Some(data) = shared_data("course_synthdata_reads_structs_and_single_arrays") else {
            return;
        };
        let f = MatFile::read(&data.join("course/synthdata.mat")).unwrap();
        let depth = f.numeric("Depth").unwrap();
        assert_eq!((depth.dims.clone(), depth.class()), (vec![480, 640], MatClass::Single));
        let image = f.numeric("Image").unwrap();
        assert_eq!(image.dims, vec![480, 640, 3]);
        // fp = f / pixelsize (data README): 0.024 / 5.625e-5 = 426.67 px.
        let fp = f.scalar("Dparam.fp").unwrap();
        let ratio = f.scalar("Dparam.f").unwrap() / f.scalar("Dparam.pixelsize").unwrap();
        assert!((fp - ratio).abs() < 1e-9 * fp, "fp {fp} vs f/pixelsize {ratio}");
        assert_eq!(f.scalar("Cparam.cx").unwrap(), 320.0);
        let err = f.scalar("Dparam.k1").unwrap_err().to_string();
        assert!(err.contains("synthdata.mat") && err.contains("no field 'k1'"), "{err}");
        // A 3-D array is not a matrix: the error says so.
        let err = f.matrix("Image").unwrap_err().to_string();
        assert!(err.contains("3 dimensions"), "{err}");
    }

    #[test]
    fn corrupt_compressed_data_is_reported() {
        let Some(data) = shared_data("corrupt_compressed_data_is_reported") else { return };
        let bytes = std::fs::read(data.join("kinect-lab/Calib_Results_stereo.mat")).unwrap();
        // Cut in the middle of the first compressed element.
        let err = MatFile::parse(&bytes[..200], Path::new("cut.mat")).unwrap_err().to_string();
        assert!(err.starts_with("cut.mat:") && err.contains("truncated"), "{err}");
        // Scramble the deflate stream of the first element (zlib's checksum catches it).
        let mut bad = bytes.clone();
        for b in &mut bad[150..190] {
            *b ^= 0x5a;
        }
        let err = MatFile::parse(&bad, Path::new("bad.mat")).unwrap_err().to_string();
        assert!(err.starts_with("bad.mat:") && err.contains("variable #1"), "{err}");
    }
}
