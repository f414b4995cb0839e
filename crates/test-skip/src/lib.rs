//! Visible, countable test skips.
//!
//! libtest counts a test that returns early as passed and hides what a passing test printed, so
//! a skip would be invisible in CI. [`skip`] prints `SKIP <test>: <reason>` and, when the
//! environment variable [`SKIP_LOG_ENV`] names a file, appends the same line to it. `.ci/run`
//! sets that variable, lists the skipped tests and reports them in its last line
//! ("N passed, M failed, K skipped").
//!
//! A skip is for a missing *optional* resource (no `../shared/data` in a plain clone, no GPU
//! adapter, no AVX2). A skip whose trigger equals the symptom of the bug a test exists to catch
//! must be an assertion instead.
#![deny(missing_docs)]

use std::io::Write;

/// Environment variable naming the file every skip is appended to (one line per skip).
pub const SKIP_LOG_ENV: &str = "KFUSE_SKIP_LOG";

/// Records that `test` was skipped because of `reason`: prints `SKIP <test>: <reason>` on
/// stderr and appends it to `$KFUSE_SKIP_LOG` when that is set.
///
/// # Panics
/// When `$KFUSE_SKIP_LOG` is set but cannot be appended to: a skip that cannot be counted
/// must not pass silently.
pub fn skip(test: &str, reason: &str) {
    let line = format!("SKIP {test}: {}", reason.replace('\n', " "));
    eprintln!("{line}");
    if let Some(path) = std::env::var_os(SKIP_LOG_ENV) {
        let path = std::path::PathBuf::from(path);
        if let Err(e) = append_line(&path, &line) {
            panic!("{test}: cannot record the skip in {} ({SKIP_LOG_ENV}): {e}", path.display());
        }
    }
}

/// Appends `line` and its newline in one `write` on a file opened for appending, so the lines
/// of tests running in parallel threads or processes never interleave.
fn append_line(path: &std::path::Path, line: &str) -> std::io::Result<()> {
    let mut file = std::fs::OpenOptions::new().create(true).append(true).open(path)?;
    file.write_all(format!("{line}\n").as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skip_lines_are_appended_one_per_call() {
        let dir = std::env::temp_dir().join(format!("test-skip-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let log = dir.join("skips.txt");
        append_line(&log, "SKIP first: no data").unwrap();
        append_line(&log, "SKIP second: no GPU adapter").unwrap();
        let text = std::fs::read_to_string(&log).unwrap();
        assert_eq!(text, "SKIP first: no data\nSKIP second: no GPU adapter\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
