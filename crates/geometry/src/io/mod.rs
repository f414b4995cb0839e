//! File input and output at the edge of the crate. Algorithms elsewhere in `geometry` never
//! open files; these modules do nothing else.

pub mod atomic;
pub mod course;
pub mod images;
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
