//! Every "§n" or "§n.m" cited in this crate's sources, its tests and benches, and in the
//! kfuse capture command and its tests, names a section of the repository's own
//! `docs/kinect-v2-protocol.md`, and nothing cites the protocol document outside the repository.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Workspace root (this crate lives in `crates/kinect-usb`).
/// The repository: from the crate folder cargo names when it runs the test (a test binary
/// reused from a checkout at another path would otherwise look there), else the one it was
/// compiled in.
fn root() -> PathBuf {
    let crate_dir = std::env::var_os("CARGO_MANIFEST_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    crate_dir.join("../..")
}

/// Section numbers ("4", "4.10") of the document's `##`/`###` headings.
fn sections(doc: &str) -> BTreeSet<String> {
    doc.lines()
        .filter_map(|l| l.strip_prefix("### ").or_else(|| l.strip_prefix("## ")))
        .filter_map(|h| h.split_whitespace().next())
        .map(|n| n.trim_end_matches('.').to_string())
        .filter(|n| n.starts_with(|c: char| c.is_ascii_digit()))
        .collect()
}

/// The section numbers cited after each "§" of `text`.
fn citations(text: &str) -> Vec<String> {
    text.split('§')
        .skip(1)
        .map(|rest| {
            let n: String = rest.chars().take_while(|c| c.is_ascii_digit() || *c == '.').collect();
            n.trim_end_matches('.').to_string()
        })
        .collect()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn every_cited_section_exists_in_the_repository_document() {
    let root = root();
    let doc = std::fs::read_to_string(root.join("docs/kinect-v2-protocol.md"))
        .expect("docs/kinect-v2-protocol.md must be in the repository");
    let known = sections(&doc);
    // The document has sections 1..16 with their subsections (spot checks of the parser).
    for s in ["1", "3.3", "4.10", "9.6", "11.3", "14.3", "16"] {
        assert!(known.contains(s), "heading {s} not parsed from the document: {known:?}");
    }
    let mut files = Vec::new();
    for d in ["crates/kinect-usb/src", "crates/kinect-usb/tests", "crates/kinect-usb/benches"] {
        rust_files(&root.join(d), &mut files);
    }
    files.push(root.join("src/cmd_capture.rs"));
    files.push(root.join("tests/capture_cli.rs"));
    let (mut cited, mut bad) = (0, Vec::new());
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        if f.ends_with("protocol_doc.rs") {
            continue;
        }
        for (i, line) in text.lines().enumerate() {
            assert!(
                !line.contains("shared/docs") && !line.contains("spec §"),
                "{}:{}: cites a document outside the repository: {line}",
                f.display(),
                i + 1
            );
            for c in citations(line) {
                cited += 1;
                if !known.contains(&c) {
                    bad.push(format!("{}:{}: §{c}", f.display(), i + 1));
                }
            }
        }
    }
    // Source: `grep -c §` over these files when this test was written gave 130 citations; the
    // guard only checks that the scan found the sources at all.
    assert!(cited > 100, "only {cited} citations found: wrong folders?");
    assert!(
        bad.is_empty(),
        "sections missing from docs/kinect-v2-protocol.md:\n{}",
        bad.join("\n")
    );
}
