//! Stage 6 of the reader: the file as a list of named variables (header, then one element per
//! variable, inflated when compressed), and look-ups by dotted path with errors naming the file.

use std::path::{Path, PathBuf};

use super::GeometryError;
use super::array::parse_matrix;
use super::compress::{MAX_INFLATED_BYTES, inflate};
use super::header::*;
use super::value::{MatMatrix, MatValue, NumericArray, describe};

/// Largest `.mat` file read: 512 MiB. The lab's files are a few MB (`KinectData.mat`, the
/// largest, holds one Kinect frame: under 20 MB); this keeps a wrong file from being read
/// whole into memory.
pub const MAX_MAT_FILE_BYTES: u64 = 512 << 20;
/// Most bytes all compressed variables of one file may inflate to together: 512 MiB (four
/// largest-size arrays), so a file of many small zlib bombs is bounded too.
pub const MAX_TOTAL_INFLATED_BYTES: u64 = 512 << 20;
/// Most memory all arrays of one file may take together: 384 MiB (three largest-size arrays).
pub const MAX_TOTAL_ARRAY_BYTES: usize = 384 << 20;

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
        let io = |source| GeometryError::Io { path: path.to_path_buf(), source };
        let expected =
            bounded_read::Expected { what: "a .mat file", fix: "is this the right file?" };
        use std::io::Read;
        // The 128-byte header first: a device, a pipe or another kind of file is refused
        // there instead of being read to the limit.
        let mut file =
            bounded_read::open_bounded(path, MAX_MAT_FILE_BYTES, expected).map_err(io)?;
        let mut head = Vec::new();
        (&mut file).take(HEADER_LEN as u64).read_to_end(&mut head).map_err(io)?;
        parse_header(&head)
            .map_err(|message| GeometryError::Format { path: path.to_path_buf(), message })?;
        let bytes = bounded_read::read_bounded_from(
            std::io::Cursor::new(head).chain(file),
            MAX_MAT_FILE_BYTES,
            expected,
        )
        .map_err(io)?;
        Self::parse(&bytes, path)
    }

    /// Parses the bytes of a file; `path` is used in error messages only.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self, GeometryError> {
        let fail = |message: String| GeometryError::Format { path: path.to_path_buf(), message };
        let (header, little) = parse_header(bytes).map_err(fail)?;
        let mut reader = Reader { bytes, pos: HEADER_LEN, little };
        let mut variables = Vec::new();
        let mut inflated_left = MAX_TOTAL_INFLATED_BYTES;
        let mut array_bytes = 0usize;
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
                inflated = inflate(data, MAX_INFLATED_BYTES.min(inflated_left)).map_err(|e| {
                    fail(format!("variable #{} at byte {at}: {e}", variables.len() + 1))
                })?;
                inflated_left -= inflated.len() as u64;
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
            array_bytes = array_bytes.saturating_add(value.memory_bytes());
            if array_bytes > MAX_TOTAL_ARRAY_BYTES {
                return Err(fail(format!(
                    "variable #{} at byte {at}: the variables so far take more than {MAX_TOTAL_ARRAY_BYTES} bytes (the limit for one file)",
                    variables.len() + 1
                )));
            }
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
