//! What a calibration run is given, checked before any work: the board of `--board`,
//! `--square`, `--top-left`; the image patterns expanded (the shell may not); the IR and colour
//! images not swapped.

use std::path::{Path, PathBuf};

use super::{CameraImages, Event, Observer};
use crate::{Board, CalibError};

/// Square sides of printed calibration boards, metres: 5-100 mm (A4 boards have 20-40 mm
/// squares, large boards up to 100 mm). Only for the hint at a number given without a unit.
const PRINTED_SQUARE_M: (f64, f64) = (0.005, 0.1);

/// Largest inner-corner count per side accepted from `--board` (far above any printed board;
/// bounds the detector's work).
const MAX_BOARD_SIDE: usize = 100;

/// Largest square side accepted from `--square`: 1 m is far above any printed board (and a unit
/// mistake such as `40m` for 40 mm lands above it).
const MAX_SQUARE_M: f64 = 1.0;
/// Smallest square side accepted from `--square`: 0.1 mm, the squares of microscope
/// calibration slides; below it is a unit mistake (`0.024mm` for 24 mm).
const MIN_SQUARE_M: f64 = 1e-4;

fn input(message: String) -> CalibError {
    CalibError::Input(message)
}

/// The board of `--board` (`COLSxROWS` inner corners, or `auto`), `--square` (a side with its
/// unit: `40mm`, `4cm`, `0.04m`) and `--top-left` (`black`/`white`, or `None`: found from the
/// images), and whether its size is to be found from the images (`auto`; the counts are then
/// placeholders).
pub fn parse_board(
    board: &str,
    square: &str,
    top_left: Option<&str>,
) -> Result<(Board, bool), CalibError> {
    let auto = board.trim().eq_ignore_ascii_case("auto");
    let (c, r) = if auto {
        (2, 2)
    } else {
        board
            .split_once(['x', 'X'])
            .and_then(|(c, r)| {
                Some((c.trim().parse::<usize>().ok()?, r.trim().parse::<usize>().ok()?))
            })
            .ok_or_else(|| {
                input(format!(
                    "--board '{board}': give inner corners as COLSxROWS, e.g. 7x5, or auto"
                ))
            })?
    };
    if c > MAX_BOARD_SIDE || r > MAX_BOARD_SIDE {
        return Err(input(format!(
            "--board '{board}': at most {MAX_BOARD_SIDE} inner corners per side"
        )));
    }
    let s = square.trim();
    let (num, scale) = if let Some(v) = s.strip_suffix("mm") {
        (v, 1e-3)
    } else if let Some(v) = s.strip_suffix("cm") {
        (v, 1e-2)
    } else if let Some(v) = s.strip_suffix('m') {
        (v, 1.0)
    } else {
        return Err(input(match s.parse::<f64>() {
            Ok(v) if v > 0.0 => {
                // The readings that give a square a printed board has (5-100 mm), first.
                let readings: Vec<String> = [("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)]
                    .into_iter()
                    .filter(|(_, m)| (PRINTED_SQUARE_M.0..=PRINTED_SQUARE_M.1).contains(&(v * m)))
                    .map(|(unit, m)| match unit {
                        "mm" => format!("{v}mm"),
                        _ => format!("{v}{unit} ({} mm)", (v * m * 1e4).round() / 10.0),
                    })
                    .collect();
                if readings.is_empty() {
                    format!(
                        "--square '{square}': give a unit: {v}mm, {}cm or {}m?",
                        v / 10.0,
                        v / 1000.0
                    )
                } else {
                    format!("--square '{square}': give a unit: {}?", readings.join(" or "))
                }
            }
            _ => format!(
                "--square '{square}': give the printed square's side with a unit, e.g. 40mm, 4cm or 0.04m"
            ),
        }));
    };
    let v: f64 = num.trim().parse().map_err(|e| CalibError::Context {
        context: format!("--square '{square}': not a number"),
        source: Box::new(e),
    })?;
    let side_m = v * scale;
    if !(MIN_SQUARE_M..=MAX_SQUARE_M).contains(&side_m) {
        return Err(input(format!(
            "--square '{square}': a square side must be between {} mm and {MAX_SQUARE_M} m; give the printed square's side, e.g. 24mm",
            MIN_SQUARE_M * 1e3
        )));
    }
    let mut b = Board::new(c, r, side_m)?;
    b.top_left_black = top_left.map(|t| t == "black");
    Ok((b, auto))
}

/// A square side given as a number of metres (the Python package's `square=0.04`), checked
/// as `--square` checks one with a unit.
pub fn square_of_metres(square_m: f64) -> Result<f64, CalibError> {
    if !(MIN_SQUARE_M..=MAX_SQUARE_M).contains(&square_m) {
        return Err(input(format!(
            "square {square_m} m: a square side must be between {} mm and {MAX_SQUARE_M} m; give the printed square's side, e.g. 0.024 (24 mm)",
            MIN_SQUARE_M * 1e3
        )));
    }
    Ok(square_m)
}

/// Natural order: `ir_2` before `ir_10`.
fn natural_key(p: &Path) -> Vec<(String, u64)> {
    let s = p.to_string_lossy();
    let mut out = Vec::new();
    let mut text = String::new();
    let mut num = String::new();
    for ch in s.chars() {
        if ch.is_ascii_digit() {
            num.push(ch);
        } else {
            if !num.is_empty() {
                out.push((std::mem::take(&mut text), num.parse().unwrap_or(u64::MAX)));
                num.clear();
            }
            text.push(ch);
        }
    }
    out.push((text, num.parse().unwrap_or(0)));
    out
}

/// Expands the patterns of `--{what}` in-process (the shell may not), naturally sorted. A
/// pattern that names an existing file is that file, taken literally: `shot[1].png` is the file
/// of that name, not the glob that matches `shot1.png`.
pub fn expand(patterns: &[String], what: &str) -> Result<Vec<PathBuf>, CalibError> {
    let mut files = Vec::new();
    for p in patterns {
        if Path::new(p).is_file() {
            files.push(PathBuf::from(p));
            continue;
        }
        let matches: Vec<PathBuf> = glob::glob(p)
            .map_err(|e| CalibError::Context {
                context: format!("--{what} '{p}': invalid glob pattern"),
                source: Box::new(e),
            })?
            .filter_map(|e| e.ok())
            .filter(|p| p.is_file())
            .collect();
        if matches.is_empty() && Path::new(p).is_dir() {
            let example = Path::new(p).join("*.png");
            return Err(input(format!(
                "--{what} '{p}' is a folder; give a pattern of its images, e.g. --{what} '{}'",
                example.display()
            )));
        }
        if matches.is_empty() {
            return Err(input(format!("--{what} '{p}': no file matches{}", no_match_hint(p))));
        }
        files.extend(matches);
    }
    files.sort_by_key(|p| natural_key(p));
    files.dedup();
    Ok(files)
}

/// The IR, colour and depth files of a run, in that order.
pub type RunFiles = (Vec<PathBuf>, Vec<PathBuf>, Vec<PathBuf>);

/// The files of `--ir`, `--color` and `--depth` ([`expand`], in that order of their messages:
/// colour first, as `kfuse calibrate` has always checked them); fails first when neither IR
/// nor colour images are given.
pub fn expand_all(
    ir: &[String],
    color: &[String],
    depth: &[String],
) -> Result<RunFiles, CalibError> {
    if color.is_empty() && ir.is_empty() {
        return Err(input(NO_IMAGES.into()));
    }
    let color = expand(color, "color")?;
    let ir = expand(ir, "ir")?;
    let depth = expand(depth, "depth")?;
    Ok((ir, color, depth))
}

/// The message of a run given neither IR nor colour images.
pub(super) const NO_IMAGES: &str =
    "give --color and/or --ir image patterns, e.g. --ir 'captures/ir_*.png'";

/// The folder of a path (`.` for a bare file name).
fn parent_folder(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Why a pattern may match nothing: the files it matches when case is ignored (`IR_*.png`
/// for `ir_0001.png`), or a folder that does not exist.
fn no_match_hint(pattern: &str) -> String {
    let options = glob::MatchOptions { case_sensitive: false, ..Default::default() };
    let ignoring_case: Vec<PathBuf> = glob::glob_with(pattern, options)
        .map(|m| m.filter_map(|e| e.ok()).filter(|p| p.is_file()).collect())
        .unwrap_or_default();
    if let Some(first) = ignoring_case.first() {
        return format!(
            "; {} file(s) match when upper and lower case are not told apart (e.g. {}): check the case",
            ignoring_case.len(),
            first.display()
        );
    }
    let folder = parent_folder(Path::new(pattern));
    if !folder.is_dir() && !folder.to_string_lossy().contains(['*', '?', '[']) {
        return format!("; the folder {} does not exist", folder.display());
    }
    String::new()
}

/// The size of a camera's first image (from its header for a file, before any work).
fn first_size(images: &CameraImages) -> Option<(usize, usize)> {
    match &images.decoded {
        Some(d) => d.first().map(|i| i.size()),
        None => images.files.first().and_then(|f| kfuse_io::image_header::image_size(f).ok()),
    }
}

/// Fails when the first IR image has the Kinect v2's colour size and the first colour image
/// its IR size: the two options swapped, which gave a rig whose depth camera is 1920x1080,
/// exit 0. With one camera only a warning ([`Event::Warning`]): other cameras may have these
/// sizes.
pub(super) fn check_not_swapped(
    ir: &CameraImages,
    color: &CameraImages,
    obs: &dyn Observer,
) -> Result<(), CalibError> {
    use kfuse_io::rig_io::show::{KINECT_COLOR_SIZE as COLOR, KINECT_DEPTH_SIZE as IR};
    match (first_size(ir), first_size(color)) {
        (Some(i), Some(c)) if (i, c) == (COLOR, IR) => Err(input(
            "the --ir images are 1920x1080 and the --color images 512x424: the Kinect v2's colour camera is the 1920x1080 one; are --ir and --color swapped?"
                .into(),
        )),
        (Some(i), None) if i == COLOR => {
            obs.event(Event::Warning(
                "the --ir images are 1920x1080, the Kinect v2's colour size: meant as --color?",
            ));
            Ok(())
        }
        (None, Some(c)) if c == IR => {
            obs.event(Event::Warning(
                "the --color images are 512x424, the Kinect v2's IR size: meant as --ir?",
            ));
            Ok(())
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--square` mistakes from a user's trial, each with a message that says the fix.
    #[test]
    fn square_sizes_need_a_unit_and_a_printable_size() {
        let side = |sq: &str| parse_board("9x6", sq, None).map(|(b, _)| b.square_m);
        let err = |sq: &str| side(sq).unwrap_err().to_string();
        assert!((side("24mm").unwrap() - 0.024).abs() < 1e-15);
        assert!((side("2.4cm").unwrap() - 0.024).abs() < 1e-15);
        // The reading that gives a printed board's square is offered (5-100 mm); otherwise
        // all three.
        assert!(err("24").contains("give a unit: 24mm?"), "{}", err("24"));
        assert!(err("0.04").contains("give a unit: 0.04m (40 mm)?"), "{}", err("0.04"));
        assert!(err("4").contains("give a unit: 4cm (40 mm)?"), "{}", err("4"));
        assert!(err("8").contains("give a unit: 8mm or 8cm (80 mm)?"), "{}", err("8"));
        assert!(err("500").contains("500mm, 50cm or 0.5m?"), "{}", err("500"));
        for bad in ["0", "-1", "abc"] {
            assert!(err(bad).contains("with a unit, e.g. 40mm"), "{bad}: {}", err(bad));
        }
        for bad in ["-1mm", "0mm", "1e-30m", "0.05mm", "2m"] {
            assert!(err(bad).contains("between 0.1 mm and 1 m"), "{bad}: {}", err(bad));
        }
        // A number of metres (Python's square=0.04) is bounded as a side with a unit.
        assert_eq!(square_of_metres(0.024).unwrap(), 0.024);
        for bad in [0.0, -0.04, 40.0, f64::NAN] {
            let e = square_of_metres(bad).unwrap_err().to_string();
            assert!(e.contains("between 0.1 mm and 1 m"), "{bad}: {e}");
        }
    }

    #[test]
    fn a_folder_given_as_a_pattern_gets_an_example() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().display().to_string();
        let err = expand(std::slice::from_ref(&d), "color").unwrap_err().to_string();
        assert!(err.contains("is a folder") && err.contains(&format!("{d}/*.png")), "{err}");
    }

    #[test]
    fn file_names_with_glob_characters_are_taken_literally() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["shot[1].png", "shot1.png", "shot2.png", "shot10.png"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        let d = dir.path().display();
        let names = |files: Vec<PathBuf>| -> Vec<String> {
            files.iter().map(|f| f.file_name().unwrap().to_string_lossy().into_owned()).collect()
        };
        // The literal file wins over the glob `shot[1].png` (which matches shot1.png).
        assert_eq!(names(expand(&[format!("{d}/shot[1].png")], "color").unwrap()), ["shot[1].png"]);
        // No such file: a glob, naturally sorted (shot2 before shot10).
        assert_eq!(
            names(expand(&[format!("{d}/shot[0-9]*.png")], "color").unwrap()),
            ["shot1.png", "shot2.png", "shot10.png"]
        );
        let err = expand(&[format!("{d}/none[1].png")], "ir").unwrap_err().to_string();
        assert!(err.contains("--ir") && err.contains("no file matches"), "{err}");
    }
}
