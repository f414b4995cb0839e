//! File input and output at the edge of the crate. Algorithms elsewhere in `geometry` never
//! open files; these modules do nothing else.
//!
//! | module | reads / writes |
//! | --- | --- |
//! | [`atomic`] | every write: temporary file + rename, [`atomic::StagedDir`] for output folders |
//! | [`mat`] | MATLAB v5 `.mat` files (reader for every numeric class, char, struct, cell; small writer) |
//! | [`course`] | the lab's `synthdata.mat` and `KinectData.mat` → [`crate::Rig`] + images |
//! | [`images`] | colour (PNG/JPEG/TIFF/BMP), depth (16-bit PNG/TIFF mm, float TIFF/EXR m), masks |
//! | [`ply`] | binary PLY point clouds and meshes (colours, `s, t` texture coordinates) |
//! | [`obj`] | OBJ + MTL + PNG texture |
//! | [`rig`] | rig JSON files |

pub mod atomic;
pub mod course;
pub mod images;
pub mod obj;
pub mod ply;
pub mod rig;
pub mod mat;

/// The shared test-data folder (`KFUSE_SHARED_DATA` or `<workspace>/../shared/data`), or
/// `None` after printing a SKIP line; panics when `KFUSE_REQUIRE_SHARED_DATA=1` (CI).
#[cfg(test)]
pub(crate) fn shared_data(test: &str) -> Option<std::path::PathBuf> {
    let dir = std::env::var_os("KFUSE_SHARED_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("KFUSE_REQUIRE_SHARED_DATA").as_deref() == Ok("1") {
        panic!("{test}: shared data not found at {} (KFUSE_REQUIRE_SHARED_DATA=1)", dir.display());
    }
    eprintln!("SKIP {test}: shared data not found at {}", dir.display());
    None
}
