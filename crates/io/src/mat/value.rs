//! Stage 5 of the reader, what it produces: [`MatValue`] trees (numeric, char, struct, cell
//! arrays), their MATLAB classes and the column-major ↔ row-major conversions.

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
    pub(super) fn from_code(code: u8) -> Self {
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

    pub(super) fn code(self) -> u8 {
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

    /// Bytes of one value.
    pub fn class_size(&self) -> usize {
        match self {
            NumericData::Double(_) | NumericData::Int64(_) | NumericData::UInt64(_) => 8,
            NumericData::Single(_) | NumericData::Int32(_) | NumericData::UInt32(_) => 4,
            NumericData::Int16(_) | NumericData::UInt16(_) => 2,
            _ => 1,
        }
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

pub(super) fn dims_text(dims: &[usize]) -> String {
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

    /// Bytes the values of this array take in memory (numbers, characters, and the same for
    /// every struct field and cell), for the reader's memory bound.
    pub fn memory_bytes(&self) -> usize {
        match self {
            MatValue::Numeric(a) => {
                let one = |d: &NumericData| d.len().saturating_mul(d.class_size());
                one(&a.real).saturating_add(a.imag.as_ref().map_or(0, one))
            }
            MatValue::Char { units, .. } => units.len() * 2,
            MatValue::Struct(s) => s
                .elements
                .iter()
                .flatten()
                .fold(0usize, |acc, v| acc.saturating_add(v.memory_bytes())),
            MatValue::Cell { cells, .. } => {
                cells.iter().fold(0usize, |acc, v| acc.saturating_add(v.memory_bytes()))
            }
            MatValue::Unsupported { .. } => 0,
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

pub(super) fn describe(v: &MatValue) -> String {
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
