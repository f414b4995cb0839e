//! The manifest that lists what kfuse wrote into an output folder.

use super::*;

/// The file in every output folder kfuse publishes that lists the entries kfuse wrote there:
/// a later run into the same folder replaces exactly those and never touches anything else.
pub const MANIFEST: &str = ".kfuse-manifest.json";
/// Prefix of staging folders (followed by the process id), inside or beside the destination.
pub(super) const STAGING_PREFIX: &str = ".kfuse-staging-";
const MANIFEST_FORMAT: &str = "kfuse-manifest";

/// The entries a folder's manifest lists (empty when there is none or it is unreadable).
pub(super) fn read_manifest(dir: &Path) -> Vec<String> {
    let Ok(text) = fs::read_to_string(dir.join(MANIFEST)) else { return Vec::new() };
    let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else { return Vec::new() };
    if value.get("format").and_then(|f| f.as_str()) != Some(MANIFEST_FORMAT) {
        return Vec::new();
    }
    value
        .get("files")
        .and_then(|f| f.as_array())
        .map(|files| {
            files
                .iter()
                .filter_map(|f| f.as_str())
                // Plain names only: a manifest never makes kfuse touch anything outside.
                .filter(|n| is_plain_name(n))
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

/// The entries of `dir` that earlier kfuse runs published there (its [`MANIFEST`]; empty when
/// there is none): a command reading its inputs from its own output folder can tell its
/// earlier outputs from the user's files.
pub fn written_by_kfuse(dir: &Path) -> Vec<String> {
    read_manifest(dir)
}

pub(super) fn manifest_json(files: &[String]) -> String {
    let value = serde_json::json!({
        "format": MANIFEST_FORMAT,
        "about": "entries of this folder written by kfuse; the next kfuse run into this folder replaces them and keeps everything else",
        "files": files,
    });
    serde_json::to_string_pretty(&value).unwrap_or_default()
}

/// A single file or folder name: not empty, no separator, not `.` or `..`.
pub fn is_plain_name(name: &str) -> bool {
    !name.is_empty()
        && name != "."
        && name != ".."
        && !name.contains('/')
        && !name.contains('\\')
        && !name.contains('\0')
}
