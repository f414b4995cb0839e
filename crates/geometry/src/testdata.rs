//! Locating the shared test data (`../shared/data` beside the workspace) for the tests,
//! benches and examples of every crate, so the rule lives in one place:
//!
//! * `KFUSE_SHARED_DATA`, when set, names the folder; otherwise it is `<workspace>/../shared/data`.
//! * When the folder is absent a test prints a visible `SKIP <test>: ...` line and returns,
//!   unless `KFUSE_REQUIRE_SHARED_DATA=1` (CI sets it), where a missing folder is a failure.
//!
//! Not used by the library's own algorithms.

use std::path::{Path, PathBuf};

/// Environment variable overriding the shared data folder.
pub const DATA_ENV: &str = "KFUSE_SHARED_DATA";

/// Environment variable that turns a missing shared data folder into a panic (CI).
pub const REQUIRE_ENV: &str = "KFUSE_REQUIRE_SHARED_DATA";

/// The shared data folder: `KFUSE_SHARED_DATA`, else `<workspace>/../shared/data`. It may not
/// exist; see [`shared_data_or_skip`].
pub fn shared_data_dir() -> PathBuf {
    resolve(std::env::var_os(DATA_ENV))
}

/// The shared data folder if it exists. Otherwise prints `SKIP <test>: ...` and returns
/// `None`, or panics when `KFUSE_REQUIRE_SHARED_DATA=1`.
pub fn shared_data_or_skip(test: &str) -> Option<PathBuf> {
    let required = std::env::var(REQUIRE_ENV).as_deref() == Ok("1");
    match existing_or_reason(test, shared_data_dir(), required) {
        Ok(dir) => Some(dir),
        Err(reason) => {
            test_skip::skip(test, &reason);
            None
        }
    }
}

fn resolve(env_value: Option<std::ffi::OsString>) -> PathBuf {
    match env_value {
        Some(v) => PathBuf::from(v),
        // This crate lives at <workspace>/crates/geometry.
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    }
}

/// The folder if it exists, else why a test must skip; panics when the folder is `required`.
fn existing_or_reason(test: &str, dir: PathBuf, required: bool) -> Result<PathBuf, String> {
    if dir.is_dir() {
        return Ok(dir);
    }
    if required {
        panic!(
            "{test}: shared data not found at {} ({REQUIRE_ENV}=1; set {DATA_ENV})",
            dir.display()
        );
    }
    Err(format!("shared data not found at {} (set {DATA_ENV})", dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_variable_names_the_folder_else_the_workspace_sibling() {
        assert_eq!(resolve(Some("/data/kinect".into())), PathBuf::from("/data/kinect"));
        let default = resolve(None);
        // <workspace>/crates/geometry/../../../shared/data = <workspace>/../shared/data
        let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().parent().unwrap();
        let expected = workspace.parent().unwrap().join("shared/data");
        assert_eq!(default.canonicalize().ok(), expected.canonicalize().ok());
        assert!(default.ends_with("shared/data"));
    }

    #[test]
    fn a_missing_folder_skips_unless_required() {
        // An existing folder: this crate's, as cargo gives it when it runs the test (the path
        // compiled in may name a checkout that no longer exists).
        let here = std::env::var_os("CARGO_MANIFEST_DIR").map(PathBuf::from).unwrap();
        assert_eq!(existing_or_reason("t", here.clone(), true), Ok(here.clone()));
        let absent = here.join("no-such-folder");
        let reason = existing_or_reason("t", absent.clone(), false).unwrap_err();
        assert!(reason.contains("no-such-folder"), "{reason}");
        let required = std::panic::catch_unwind(|| existing_or_reason("t", absent, true));
        assert!(required.is_err(), "a required folder that is missing must fail the test");
    }
}
