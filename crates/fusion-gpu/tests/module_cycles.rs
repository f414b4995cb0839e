//! No import cycle between the crate's modules: every `crate::…` and `super::…` path in
//! `src/` (comments left out) is an edge from the file's module to the module it names, and
//! the graph must have no cycle. Nodes are the top-level modules (`src/x.rs` or `src/x/`); a
//! folder's own files are a second graph (its `mod.rs`, the shared part they may all use, is
//! left out of it). Names the crate root re-exports (`crate::GpuError`) count as their module.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// `module → modules it uses`, for the top level (`""`) and per folder.
type Graphs = BTreeMap<String, BTreeMap<String, BTreeSet<String>>>;

/// The code of a file without `//` comments (doc comments name modules in links).
fn code(source: &str) -> String {
    source.lines().map(|l| l.find("//").map_or(l, |i| &l[..i])).collect::<Vec<_>>().join("\n")
}

/// Every path that follows `prefix` (`crate::` or `super::`), as its segments, with `use`
/// groups (`crate::{a, b::c}`) expanded one level.
fn paths(code: &str, prefix: &str) -> Vec<Vec<String>> {
    let ident = |c: char| c.is_alphanumeric() || c == '_';
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find(prefix) {
        let before = rest[..i].chars().next_back();
        rest = &rest[i + prefix.len()..];
        if before.is_some_and(|c| ident(c) || c == ':') {
            continue;
        }
        let head: String = rest.chars().take_while(|&c| ident(c) || c == ':').collect();
        let segments: Vec<String> =
            head.split("::").filter(|s| !s.is_empty()).map(String::from).collect();
        if rest[head.len()..].starts_with('{') || head.is_empty() && rest.starts_with('{') {
            let group = &rest[head.len()..];
            let end = group.find('}').unwrap_or(group.len());
            for item in group[1..end].split(',') {
                let item: String = item.trim().chars().take_while(|&c| ident(c)).collect();
                if !item.is_empty() {
                    out.push(segments.iter().cloned().chain([item]).collect());
                }
            }
        } else if !segments.is_empty() {
            out.push(segments);
        }
    }
    out
}

/// `name → module` of the crate root's `pub use module::{…}` re-exports.
fn reexports(lib: &str) -> BTreeMap<String, String> {
    let mut map = BTreeMap::new();
    for line in code(lib).lines() {
        let Some(rest) = line.trim().strip_prefix("pub use ") else { continue };
        for p in paths(&format!("crate::{rest}"), "crate::") {
            if p.len() >= 2 {
                map.insert(p[p.len() - 1].clone(), p[0].clone());
            }
        }
    }
    map
}

/// The module graphs of the crate whose sources are in `src`.
fn graphs(src: &Path) -> Graphs {
    let lib = std::fs::read_to_string(src.join("lib.rs")).expect("src/lib.rs");
    let roots = reexports(&lib);
    let mut files = Vec::new();
    let mut dirs = vec![src.to_path_buf()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).expect("src readable").flatten() {
            let p = e.path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                files.push(p);
            }
        }
    }
    let mut g = Graphs::new();
    for file in files {
        let rel = file.strip_prefix(src).expect("under src").with_extension("");
        let parts: Vec<String> = rel.iter().map(|s| s.to_string_lossy().into_owned()).collect();
        if parts == ["lib"] {
            continue;
        }
        // This file's module path: `stages/mod.rs` is `stages`, `stages/plane.rs` `stages::plane`.
        let module: Vec<String> = match parts.split_last() {
            Some((last, dir)) if last == "mod" => dir.to_vec(),
            _ => parts.clone(),
        };
        let source = code(&std::fs::read_to_string(&file).expect("readable"));
        let mut used: Vec<Vec<String>> = paths(&source, "crate::");
        if module.len() >= 2 {
            let parent = &module[..module.len() - 1];
            for p in paths(&source, "super::") {
                used.push(parent.iter().cloned().chain(p).collect());
            }
        }
        for mut target in used {
            if target.len() == 1
                && let Some(m) = roots.get(&target[0])
            {
                target = vec![m.clone()];
            }
            add_edges(&mut g, &module, &target);
        }
        g.entry(String::new()).or_default().entry(module[0].clone()).or_default();
    }
    g
}

/// The edges `from → to` gives: at the top level between their first segments, and inside
/// each folder both lie in, between their children there (the folder's `mod.rs` excluded).
fn add_edges(g: &mut Graphs, from: &[String], to: &[String]) {
    let mut depth = 0;
    while depth < from.len() && depth < to.len() {
        let (a, b) = (&from[depth], &to[depth]);
        if a != b {
            // `to` may name an item of the folder's mod.rs rather than a child module; only a
            // path with a further segment is certainly a module.
            if depth == 0 || to.len() > depth + 1 {
                let folder = from[..depth].join("::");
                g.entry(folder).or_default().entry(a.clone()).or_default().insert(b.clone());
            }
            return;
        }
        depth += 1;
    }
}

/// A cycle of `graph`, as the modules on it, if there is one.
fn cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        stack.push(n.to_string());
        for m in graph.get(n).into_iter().flatten() {
            match state.get(m.as_str()) {
                Some(1) => {
                    let start = stack.iter().position(|s| s == m).unwrap_or(0);
                    let mut c = stack[start..].to_vec();
                    c.push(m.clone());
                    return Some(c);
                }
                Some(_) => {}
                None => {
                    if let Some(c) = visit(m, graph, state, stack) {
                        return Some(c);
                    }
                }
            }
        }
        stack.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in graph.keys() {
        if !state.contains_key(n.as_str())
            && let Some(c) = visit(n, graph, &mut state, &mut Vec::new())
        {
            return Some(c);
        }
    }
    None
}

fn first_cycle(g: &Graphs) -> Option<(String, Vec<String>)> {
    g.iter().find_map(|(folder, graph)| cycle(graph).map(|c| (folder.clone(), c)))
}

#[test]
fn the_crate_s_modules_import_each_other_without_a_cycle() {
    let src = manifest_dir().join("src");
    let g = graphs(&src);
    // The scan sees the edges that matter: the context uses the stages, a stage the device.
    let top = &g[""];
    assert!(top["context"].contains("stages"), "{top:?}");
    assert!(top["stages"].contains("gpu"), "{top:?}");
    assert!(top["decode"].contains("context"), "{top:?}");
    if let Some((folder, c)) = first_cycle(&g) {
        panic!("import cycle in `{folder}` (top level if empty): {}", c.join(" -> "));
    }
}

#[test]
fn a_cycle_is_found() {
    // The graph as it stood before the stages owned their state: context ↔ submit ↔
    // stages::plane (plane.rs used the context's uniform table).
    let dir = tempfile::tempdir().expect("temp dir");
    let src = dir.path();
    std::fs::create_dir(src.join("stages")).expect("mkdir");
    let files = [
        ("lib.rs", "mod context;\nmod stages;\nmod submit;\npub use context::FusionContext;\n"),
        ("context.rs", "use crate::stages::plane;\nuse crate::submit::write_padded;\n"),
        ("submit.rs", "use crate::FusionContext; // a re-export of the root\n"),
        ("stages/mod.rs", "pub(crate) mod plane;\n"),
        ("stages/plane.rs", "use super::Shader;\nuse crate::context::{FusionContext, U_PLANE};\n"),
    ];
    for (name, text) in files {
        std::fs::write(src.join(name), text).expect("write");
    }
    let (folder, c) = first_cycle(&graphs(src)).expect("the cycle is found");
    assert_eq!(folder, "");
    assert!(c.contains(&"context".to_string()) && c.len() >= 3, "{c:?}");
    // Without plane's use of the context and submit's of the root, no cycle is left.
    std::fs::write(src.join("stages/plane.rs"), "use super::Shader;\n").expect("write");
    std::fs::write(src.join("submit.rs"), "\n").expect("write");
    assert_eq!(first_cycle(&graphs(src)), None);
}

/// This package's folder from the `CARGO_MANIFEST_DIR` cargo sets when it runs the test, not
/// the path compiled in: a test binary reused from a checkout at another path (a shared target
/// directory) must read this checkout's files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map(std::path::PathBuf::from).expect("run by cargo test")
}
