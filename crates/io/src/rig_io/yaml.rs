//! Reading the YAML of OpenCV's `cv::FileStorage` and of ROS `camera_info` files with
//! `serde_yaml_ng` (libyaml), plus the two quirks of OpenCV's dialect:
//!
//! * **The `%YAML:1.0` header.** OpenCV writes the YAML directive with a colon, which is not
//!   YAML syntax (`%YAML 1.0` would be) and which libyaml rejects. When the file's first line
//!   starts with `%YAML:` that line is dropped before parsing (the document marker `---`
//!   that follows it stays); any other first line is parsed as it is.
//! * **The `!!opencv-matrix` tag.** OpenCV writes matrices as a mapping tagged
//!   `!!opencv-matrix` with `rows`, `cols`, `dt` and `data`. libyaml expands `!!` to the
//!   core-schema prefix `tag:yaml.org,2002:`, and serde_yaml_ng treats such tags as type
//!   hints and drops them, so the matrix arrives as the plain mapping (measured in this
//!   module's tests). [`Doc::matrix`] reads that mapping; should a tagged value arrive (a
//!   local tag such as `!opencv-matrix`), it unwraps `opencv-matrix` and refuses any other
//!   tag by name. ROS writes the same `rows`/`cols`/`data` mapping without a tag, and a plain
//!   sequence of numbers is accepted as a `1 × n` matrix.
//!
//! Before any parsing the text is bounded: at most [`MAX_YAML_BYTES`] and at most
//! [`MAX_YAML_DEPTH`] levels of nesting ([`check_nesting`]). libyaml's parser plus
//! serde_yaml_ng's event handling grow faster than linearly with the nesting: 100 kB of nested
//! brackets took 9.6 s and 400 kB more than 60 s (red-team finding), where a calibration file
//! nests 3 levels.

use std::path::{Path, PathBuf};

use geometry::GeometryError;
use serde_yaml_ng::Value;

/// Largest calibration text file read (a rig YAML is ~2 KB; this bounds a wrong file).
pub const MAX_TEXT_BYTES: u64 = 4 << 20;
/// Largest matrix read from a calibration file: OpenCV's `Q` is 4 × 4, distortion vectors
/// have at most 14 entries; 64 leaves room and bounds a corrupt `rows × cols`.
const MAX_MATRIX_VALUES: usize = 64;
/// Largest image side accepted from a file (a 16k sensor is 16 384 px wide).
pub const MAX_IMAGE_SIDE: u64 = 65_536;
/// Largest YAML document parsed, bytes: 1 MiB. A rig or camera_info YAML is 1–3 KB; OpenCV's
/// calibration sample with every view's image points (100 views × 100 corners: 20 000
/// numbers of ~25 characters) would be about 500 KB. Measured (debug build, 2026-12-03): 1 MB of flat values parses in 0.05–0.08 s of CPU,
/// 1 MB of 16-level brackets repeated (the worst within both limits) in 0.2 s.
pub const MAX_YAML_BYTES: usize = 1 << 20;
/// Deepest nesting of a YAML document (block indentation levels, `- ` entries and flow
/// brackets together): 16. OpenCV FileStorage and ROS files nest 3 levels (a matrix mapping
/// holding a `data` list); nested brackets are what made the parser take minutes.
pub const MAX_YAML_DEPTH: usize = 16;

/// A format error naming the file.
pub fn fmt_err(path: &Path, message: impl Into<String>) -> GeometryError {
    GeometryError::Format { path: path.to_path_buf(), message: message.into() }
}

/// Reads a text file of at most [`MAX_TEXT_BYTES`], whatever the file is (a device or a pipe
/// states no size; see [`bounded_read`]).
pub fn read_text(path: &Path) -> Result<String, GeometryError> {
    let io = |source| GeometryError::Io { path: path.to_path_buf(), source };
    let expected = bounded_read::Expected {
        what: "a calibration file",
        fix: "is this the right file? Give the calibration's YAML or JSON file",
    };
    let bytes = bounded_read::read_bounded(path, MAX_TEXT_BYTES, expected).map_err(io)?;
    let len = bytes.len();
    let text = String::from_utf8(bytes)
        .map_err(|_| fmt_err(path, "binary data, not a text calibration file (YAML or JSON)"))?;
    if text.trim_start_matches('\u{feff}').trim().is_empty() {
        return Err(fmt_err(
            path,
            format!(
                "is empty ({len} bytes{}): no calibration in it; was it saved completely? Save or export the calibration again",
                if len > 0 { ", all blank" } else { "" }
            ),
        ));
    }
    Ok(text)
}

/// A parsed YAML document: a top-level mapping and the file it came from.
#[derive(Debug, Clone)]
pub struct Doc {
    path: PathBuf,
    map: serde_yaml_ng::Mapping,
}

/// True when `text` is OpenCV FileStorage YAML (starts with its `%YAML:` header).
pub fn has_opencv_header(text: &str) -> bool {
    text.trim_start_matches('\u{feff}').starts_with("%YAML:")
}

/// The deepest nesting of YAML `text`, counted without parsing: block indentation levels of
/// the lines, `- ` sequence entries opened on one line, and `[`/`{` flow brackets outside
/// quoted scalars and comments. Stops counting (returns early) as soon as `limit` is passed,
/// so the cost is one pass over the text at most.
pub fn nesting_depth(text: &str, limit: usize) -> usize {
    let mut indents: Vec<usize> = Vec::new();
    let mut flow = 0usize;
    let mut deepest = 0usize;
    // The block depth of the line a flow collection started on (indentation levels and the
    // line's `- ` entries); flow brackets nest below it.
    let mut base = 0usize;
    // Inside a quoted scalar: its quote character (quoted scalars may span lines).
    let mut quote: Option<char> = None;
    for line in text.lines() {
        let mut chars = line.chars().peekable();
        let mut indent = 0;
        if quote.is_none() && flow == 0 {
            while chars.peek() == Some(&' ') {
                chars.next();
                indent += 1;
            }
            let rest: String = chars.clone().collect();
            let rest = rest.trim_end();
            if rest.is_empty() || rest.starts_with('#') {
                continue;
            }
            while indents.last().is_some_and(|&i| i > indent) {
                indents.pop();
            }
            if indents.last() != Some(&indent) {
                indents.push(indent);
            }
            // `- - - x` opens a sequence per dash on one line.
            let mut dashes = 0usize;
            let mut r = rest;
            while let Some(after) = r.strip_prefix("- ").or_else(|| (r == "-").then_some("")) {
                dashes += 1;
                r = after.trim_start();
            }
            // The first `- ` is the sequence at this indentation (counted above); each
            // further one on the line opens a nested sequence.
            base = indents.len() + dashes.saturating_sub(1);
            deepest = deepest.max(base);
        }
        // The character before the current one that was not a space: a quote opens a
        // quoted scalar only where a scalar can start (line start, after `:`, `,`, `[`, `{`,
        // `-`, `?`); elsewhere (`kinect's`) it is part of a plain scalar.
        let mut prev: Option<char> = None;
        let mut escaped = false;
        for c in chars {
            match quote {
                Some('"') => {
                    if escaped {
                        escaped = false;
                    } else if c == '\\' {
                        escaped = true;
                    } else if c == '"' {
                        quote = None;
                    }
                }
                Some(_) => {
                    if c == '\'' {
                        quote = None;
                    }
                }
                None => match c {
                    '#' if prev.is_none_or(char::is_whitespace) => break,
                    '"' | '\'' if prev.is_none_or(|p| " \t:,[{-?".contains(p)) => quote = Some(c),
                    '[' | '{' => {
                        flow += 1;
                        deepest = deepest.max(base + flow);
                    }
                    ']' | '}' => flow = flow.saturating_sub(1),
                    _ => {}
                },
            }
            prev = Some(c);
            if deepest > limit {
                return deepest;
            }
        }
        if deepest > limit {
            return deepest;
        }
    }
    deepest
}

/// Refuses, before parsing, YAML text over [`MAX_YAML_BYTES`] or nested deeper than
/// [`MAX_YAML_DEPTH`] (module docs), with one line naming the file.
pub fn check_nesting(text: &str, path: &Path) -> Result<(), GeometryError> {
    if text.len() > MAX_YAML_BYTES {
        return Err(fmt_err(
            path,
            format!(
                "{} bytes is too large for a calibration YAML file (limit {MAX_YAML_BYTES}); is this the right file?",
                text.len()
            ),
        ));
    }
    let depth = nesting_depth(text, MAX_YAML_DEPTH);
    if depth > MAX_YAML_DEPTH {
        return Err(fmt_err(
            path,
            format!(
                "nested more than {MAX_YAML_DEPTH} levels deep, which no calibration file is (OpenCV and ROS files nest 3); is this the right file?"
            ),
        ));
    }
    Ok(())
}

impl Doc {
    /// Parses `text` (see the module docs for the OpenCV header and the bounds checked first).
    pub fn parse(text: &str, path: &Path) -> Result<Self, GeometryError> {
        check_nesting(text, path)?;
        let text = text.trim_start_matches('\u{feff}');
        let body = if has_opencv_header(text) {
            text.split_once('\n').map(|(_, rest)| rest).unwrap_or("")
        } else {
            text
        };
        let value: Value = serde_yaml_ng::from_str(body)
            .map_err(|e| fmt_err(path, format!("not valid YAML ({e})")))?;
        match value {
            Value::Mapping(map) => Ok(Doc { path: path.to_path_buf(), map }),
            _ => Err(fmt_err(path, "the YAML document is not a mapping of names to values")),
        }
    }

    /// Reads and parses a file.
    pub fn read(path: &Path) -> Result<Self, GeometryError> {
        Self::parse(&read_text(path)?, path)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Adds the entries of `other` (a second file of the same calibration, e.g. OpenCV's
    /// `intrinsics.yml` + `extrinsics.yml`). A name present in both with different values is
    /// an error naming both files.
    pub fn merge(&mut self, other: Doc) -> Result<(), GeometryError> {
        for (k, v) in other.map {
            if let Some(mine) = self.map.get(&k) {
                if *mine != v {
                    return Err(fmt_err(
                        &other.path,
                        format!(
                            "'{}' differs from the one in {}; give files of one calibration",
                            k.as_str().unwrap_or("?"),
                            self.path.display()
                        ),
                    ));
                }
                continue;
            }
            self.map.insert(k, v);
        }
        Ok(())
    }

    /// True when the document has entry `key`.
    pub fn has(&self, key: &str) -> bool {
        self.map.contains_key(key)
    }

    /// The first of `keys` present, with its name.
    pub fn first_of<'a>(&self, keys: &[&'a str]) -> Option<(&'a str, &Value)> {
        keys.iter().find_map(|k| self.map.get(*k).map(|v| (*k, v)))
    }

    /// A string entry.
    pub fn string(&self, key: &str) -> Option<String> {
        self.map.get(key).and_then(untagged).and_then(|v| v.as_str().map(str::to_owned))
    }

    /// A plain number entry (`depthShift: -13.35`); `None` when absent, an error naming the
    /// key when it is not a finite number.
    pub fn number(&self, key: &str) -> Result<Option<f64>, GeometryError> {
        let Some(v) = self.map.get(key) else { return Ok(None) };
        match untagged(v).and_then(Value::as_f64).filter(|x| x.is_finite()) {
            Some(x) => Ok(Some(x)),
            None => Err(fmt_err(&self.path, format!("'{key}' must be a finite number"))),
        }
    }

    /// An image side (`image_width`, ...), bounded by [`MAX_IMAGE_SIDE`].
    pub fn size(&self, key: &str) -> Result<Option<usize>, GeometryError> {
        let Some(v) = self.map.get(key) else { return Ok(None) };
        match untagged(v).and_then(Value::as_u64) {
            Some(n) if (1..=MAX_IMAGE_SIDE).contains(&n) => Ok(Some(n as usize)),
            _ => Err(fmt_err(
                &self.path,
                format!("'{key}' must be a whole number of pixels in 1..={MAX_IMAGE_SIDE}"),
            )),
        }
    }

    /// Matrix entry `key` as `(rows, cols, row-major values)`; `None` when absent.
    pub fn matrix(&self, key: &str) -> Result<Option<(usize, usize, Vec<f64>)>, GeometryError> {
        let Some(v) = self.map.get(key) else { return Ok(None) };
        let err = |m: String| fmt_err(&self.path, format!("'{key}': {m}"));
        let v = match v {
            Value::Tagged(t) => {
                if !is_opencv_matrix_tag(&t.tag.to_string()) {
                    return Err(err(format!(
                        "tag {} is not supported (expected !!opencv-matrix)",
                        t.tag
                    )));
                }
                &t.value
            }
            v => v,
        };
        if let Value::Sequence(seq) = v {
            let data = numbers(seq).map_err(err)?;
            if data.len() > MAX_MATRIX_VALUES {
                return Err(err(format!("{} values, at most {MAX_MATRIX_VALUES}", data.len())));
            }
            return Ok(Some((1, data.len(), data)));
        }
        let Value::Mapping(m) = v else {
            return Err(err("expected a matrix (rows, cols, data)".into()));
        };
        let dim = |name: &str| -> Result<usize, GeometryError> {
            m.get(name)
                .and_then(Value::as_u64)
                .filter(|&n| (1..=MAX_MATRIX_VALUES as u64).contains(&n))
                .map(|n| n as usize)
                .ok_or_else(|| {
                    err(format!("'{name}' must be a whole number in 1..={MAX_MATRIX_VALUES}"))
                })
        };
        let (rows, cols) = (dim("rows")?, dim("cols")?);
        if rows * cols > MAX_MATRIX_VALUES {
            return Err(err(format!("{rows}×{cols} is larger than {MAX_MATRIX_VALUES} values")));
        }
        let data = match m.get("data") {
            Some(Value::Sequence(seq)) => numbers(seq).map_err(err)?,
            _ => return Err(err("no 'data' list".into())),
        };
        if data.len() != rows * cols {
            return Err(err(format!("{rows}×{cols} but 'data' has {} values", data.len())));
        }
        Ok(Some((rows, cols, data)))
    }

    /// Matrix `key` that must exist and hold `n` values (any shape with `n` entries, so a
    /// 3×1 and a 1×3 `T` are both accepted).
    pub fn values(&self, key: &str, n: usize) -> Result<Vec<f64>, GeometryError> {
        match self.matrix(key)? {
            Some((_, _, d)) if d.len() == n => Ok(d),
            Some((r, c, _)) => {
                Err(fmt_err(&self.path, format!("'{key}' is {r}×{c}, expected {n} values")))
            }
            None => Err(fmt_err(&self.path, format!("no '{key}'"))),
        }
    }
}

/// libyaml expands `!!opencv-matrix` to the secondary handle's prefix; accept both spellings.
fn is_opencv_matrix_tag(tag: &str) -> bool {
    let tag = tag.trim_start_matches('!');
    tag == "opencv-matrix" || tag == "tag:yaml.org,2002:opencv-matrix"
}

fn untagged(v: &Value) -> Option<&Value> {
    match v {
        Value::Tagged(t) => Some(&t.value),
        v => Some(v),
    }
}

/// Longest part of a file's text value shown in a message, characters.
const MAX_SHOWN_CHARS: usize = 40;

/// A YAML value in a message: numbers and short text as they are, containers by kind (never
/// Rust's debug form of the parser's types).
fn shown(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.as_f64().map(geometry::num_fmt::num).unwrap_or_else(|| n.to_string()),
        Value::String(s) => {
            let mut t: String = s.escape_debug().take(MAX_SHOWN_CHARS).collect();
            if s.escape_debug().nth(MAX_SHOWN_CHARS).is_some() {
                t.push('…');
            }
            format!("'{t}'")
        }
        Value::Sequence(_) => "a list".into(),
        Value::Mapping(_) => "a mapping".into(),
        Value::Tagged(t) => format!("a value tagged {}", t.tag),
    }
}

fn numbers(seq: &[Value]) -> Result<Vec<f64>, String> {
    seq.iter()
        .map(|v| {
            let n = match v {
                Value::Number(n) => n.as_f64(),
                // OpenCV writes NaN and infinities as .Nan / .Inf, which parse as numbers; a
                // string here is never a number.
                _ => None,
            };
            n.filter(|x| x.is_finite())
                .ok_or_else(|| format!("{} is not a finite number", shown(v)))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `/dev/zero` and a FIFO that never ends, given as a calibration file, are refused after
    /// [`MAX_TEXT_BYTES`] + 1 bytes (they stated a size of 0 and were read to 4 GB): the
    /// FIFO's writer got at most the limit, the pipe buffer and one chunk into the pipe.
    #[test]
    fn devices_and_pipes_are_read_to_the_limit_only() {
        use std::io::Write;
        let e = read_text(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(e.starts_with("/dev/zero: "), "{e}");
        assert!(e.contains(&format!("more than {MAX_TEXT_BYTES} bytes")), "{e}");
        assert!(e.contains("a calibration file"), "{e}");

        let dir = std::env::temp_dir().join(format!("kfuse-calib-fifo-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("rig.yml");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
        const CHUNK: usize = 64 << 10;
        let writer = {
            let fifo = fifo.clone();
            std::thread::spawn(move || {
                let mut f = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
                let mut sent = 0u64;
                while f.write_all(&[b'a'; CHUNK]).is_ok() {
                    sent += CHUNK as u64;
                }
                sent
            })
        };
        let e = read_text(&fifo).unwrap_err().to_string();
        let sent = writer.join().unwrap();
        assert!(e.contains(&format!("more than {MAX_TEXT_BYTES} bytes")), "{e}");
        // 1 MiB: Linux's largest pipe buffer.
        assert!(sent > MAX_TEXT_BYTES && sent <= MAX_TEXT_BYTES + (1 << 20) + CHUNK as u64);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn opencv_header_and_matrix_tag_are_understood() {
        let text = "%YAML:1.0\n---\nimage_width: 640\nM1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 5.0000000000000000e+02, 0., 3.195e+02, 0., 5.01e+02,\n       2.395e+02, 0., 0., 1. ]\nT: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ -5.2e+01, 1.5e-01, .5 ]\n";
        let doc = Doc::parse(text, Path::new("x.yml")).unwrap();
        assert_eq!(doc.size("image_width").unwrap(), Some(640));
        let (r, c, m) = doc.matrix("M1").unwrap().unwrap();
        assert_eq!((r, c), (3, 3));
        assert_eq!(m, vec![500.0, 0.0, 319.5, 0.0, 501.0, 239.5, 0.0, 0.0, 1.0]);
        assert_eq!(doc.values("T", 3).unwrap(), vec![-52.0, 0.15, 0.5]);
        // Without dropping the header libyaml refuses the file: the quirk is real.
        assert!(serde_yaml_ng::from_str::<Value>(text).is_err());
    }

    /// The red-team's 400 kB of nested brackets (which kept `rig import` busy for more than
    /// 60 s) and a 2 MiB file are refused before parsing, with one line naming the file; real
    /// files pass: OpenCV's and ROS's layouts (3 levels), brackets and quotes inside quoted
    /// strings and comments.
    #[test]
    fn oversized_and_deeply_nested_yaml_is_refused_before_parsing() {
        let path = Path::new("deep.yaml");
        let deep = format!("a: {}", "[".repeat(400_000));
        let e = Doc::parse(&deep, path).unwrap_err().to_string();
        assert!(e.starts_with("deep.yaml: nested more than 16 levels") && !e.contains('\n'), "{e}");
        let blocks: String = (0..40).map(|i| format!("{}k{i}:\n", " ".repeat(i))).collect();
        assert!(Doc::parse(&blocks, path).unwrap_err().to_string().contains("nested more than"));
        let dashes = format!("a:\n  {}x\n", "- ".repeat(40));
        assert!(Doc::parse(&dashes, path).unwrap_err().to_string().contains("nested more than"));
        let big = format!("a: [{}]\n", "1, ".repeat(MAX_YAML_BYTES / 3));
        let e = Doc::parse(&big, Path::new("big.yaml")).unwrap_err().to_string();
        assert!(
            e.starts_with("big.yaml: ") && e.contains("too large for a calibration YAML"),
            "{e}"
        );
        // Exactly at the limit of 16 flow levels: accepted.
        let at_limit = format!("a: {}1{}\n", "[".repeat(15), "]".repeat(15));
        assert!(Doc::parse(&at_limit, path).is_ok());
        let real = "%YAML:1.0\n---\nM1: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ 1., 2., 3. ]\nnote: \"[[[[[[[[[[[[[[[[[[[[\"\nother: '{{{{{{{{{{{{{{{{{{{{{{{{{{'\n# [[[[[[[[[[[[[[[[[[[[[[[[[[[\ncamera_name: kinect's ir\nlist:\n  - [1, 2]\n  - {a: [3]}\n";
        // The top mapping, `list`, its entry `{a: …}`, `[3]`.
        assert_eq!(nesting_depth(real, MAX_YAML_DEPTH), 4);
        // kinect2_calibration's layout: the top mapping, a matrix, its `data` list.
        assert_eq!(nesting_depth(&real[..real.find("note:").unwrap()], MAX_YAML_DEPTH), 3);
        let doc = Doc::parse(real, path).unwrap();
        assert_eq!(doc.values("M1", 3).unwrap(), vec![1.0, 2.0, 3.0]);
    }

    #[test]
    fn wrong_shapes_and_values_are_named() {
        let doc = Doc::parse(
            "A: {rows: 2, cols: 2, data: [1, 2, 3]}\nB: !foo {rows: 1, cols: 1, data: [1]}\nC: {rows: 100000, cols: 100000, data: []}\nD: [1, x]\nw: -3\n",
            Path::new("bad.yaml"),
        )
        .unwrap();
        let e = |r: Result<_, GeometryError>| r.err().map(|e| e.to_string()).unwrap_or_default();
        let a = e(doc.matrix("A"));
        assert!(a.contains("bad.yaml: 'A': 2×2 but 'data' has 3 values"), "{a}");
        assert!(e(doc.matrix("B")).contains("not supported"), "{}", e(doc.matrix("B")));
        assert!(e(doc.matrix("C")).contains("'rows' must be"));
        assert!(e(doc.matrix("D")).contains("not a finite number"));
        let size_err = doc.size("w").unwrap_err().to_string();
        assert!(size_err.contains("whole number of pixels"), "{size_err}");
        assert!(doc.matrix("nope").unwrap().is_none());
    }
}
