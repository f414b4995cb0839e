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
//! convert them (see [`crate::course`]).
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
//! use kfuse_io::mat::MatFile;
//! let file = MatFile::read("Calib_Results_left.mat".as_ref())?;
//! let fc = file.matrix("fc")?; // 2×1
//! let fx = fc.data[0];
//! let cx = file.scalar("Cparam.cx").ok(); // struct field, dotted path
//! # Ok::<(), geometry::GeometryError>(())
//! ```
//!
//! # Stages
//!
//! | stage | file | reads | produces |
//! | --- | --- | --- | --- |
//! | 1 header / tags | `header.rs` | 128-byte header, element tags | byte order, `(type, bytes)` per element |
//! | 2 element values | `element.rs` | one numeric element | numbers in the array's class |
//! | 3 compression | `compress.rs` | an `miCOMPRESSED` element | the inflated element |
//! | 4 arrays | `array.rs` | an `miMATRIX` element | `(name, MatValue)`, recursing into structs and cells |
//! | 5 values | `value.rs` | — | [`MatValue`], [`NumericArray`], layout conversions |
//! | 6 file | `file.rs` | the whole file | [`MatFile`]: variables and dotted-path look-ups |
//! | 7 course layer | [`crate::course`] | `synthdata.mat`, `KinectData.mat` | a rig and images |
//!
//! The writer (`write.rs`) produces uncompressed little-endian files for tests and exports.

use geometry::GeometryError;

mod array;
mod compress;
mod element;
mod file;
mod header;
mod value;
mod write;

pub use array::MAX_ARRAY_BYTES;
pub use compress::MAX_INFLATED_BYTES;
pub use file::{MAX_MAT_FILE_BYTES, MAX_TOTAL_ARRAY_BYTES, MAX_TOTAL_INFLATED_BYTES, MatFile};
pub use value::{
    MatClass, MatMatrix, MatValue, NumericArray, NumericData, StructArray, column_to_row_major,
    row_to_column_major,
};
pub use write::{encode, write_mat};

#[cfg(test)]
mod tests;
