//! The files of a joint calibration: which camera an image belongs to, and which board pose
//! (view id) it shows.
//!
//! * **View id**: the shot number in the file's name, the last run of digits of its stem
//!   (`ir_0007.png` → 7, `cam2_shot12.jpg` → 12). The same id in two cameras is the same board
//!   pose. A camera whose file carries no number, or two files of one camera with the same
//!   number (`ir_7.png`, `ir_007.png`), is an error naming the files.
//! * **Camera names**: `SENSOR.depth` (or `SENSOR.ir`) is a Kinect's depth camera, `SENSOR.color`
//!   its colour camera, with `SENSOR` its sensor; any other name is a camera of no sensor.
//! * **A multi-sensor capture folder** (`kfuse capture calib --device …`): every sub-folder
//!   `SERIAL/` with `ir_*` images gives `SERIAL.depth`, with `color_*` images `SERIAL.color`,
//!   the names of the capture's `true_rig.json`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use geometry::CameraRole;

use crate::{Board, CalibError, ViewCorners};

/// Most digits of a view id: 18 (every such number fits a `u64`).
pub const MAX_VIEW_ID_DIGITS: usize = 18;

/// Most sensor folders read from one capture folder: 16, far above the
/// [`super::MAX_CAMERAS`] the joint fit takes; bounds the listing of a wrong folder.
pub const MAX_SENSOR_FOLDERS: usize = 16;

/// Image name extensions taken from a capture folder (what `kfuse capture` writes and the
/// readers read).
const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "bmp", "tif", "tiff"];

/// The view id of a file: the last run of ASCII digits of its stem (module docs), `None`
/// when the stem has none or the run is longer than [`MAX_VIEW_ID_DIGITS`].
pub fn view_id(path: &Path) -> Option<u64> {
    let stem = path.file_stem()?.to_string_lossy();
    let bytes = stem.as_bytes();
    let end = bytes.iter().rposition(u8::is_ascii_digit)? + 1;
    let start = bytes[..end].iter().rposition(|b| !b.is_ascii_digit()).map_or(0, |i| i + 1);
    if end - start > MAX_VIEW_ID_DIGITS {
        return None;
    }
    stem[start..end].parse().ok()
}

/// The role and sensor a camera's name gives (module docs).
pub fn role_of(name: &str) -> (CameraRole, Option<String>) {
    match name.rsplit_once('.') {
        Some((s, "depth" | "ir")) if !s.is_empty() => (CameraRole::Depth, Some(s.to_string())),
        Some((s, "color" | "colour")) if !s.is_empty() => (CameraRole::Color, Some(s.to_string())),
        _ => (CameraRole::Camera, None),
    }
}

/// One camera's images by view id.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFiles {
    /// The camera's name.
    pub name: String,
    /// Its role (from the name, [`role_of`]).
    pub role: CameraRole,
    /// Its sensor (from the name).
    pub sensor: Option<String>,
    /// Its images by view id.
    pub files: BTreeMap<u64, PathBuf>,
}

/// Files named in a message: the first few, then how many more.
fn list(files: &[&Path]) -> String {
    /// Files named in one message before "and N more".
    const SHOWN: usize = 3;
    let mut s: Vec<String> = files.iter().take(SHOWN).map(|f| f.display().to_string()).collect();
    if files.len() > SHOWN {
        s.push(format!("and {} more", files.len() - SHOWN));
    }
    s.join(", ")
}

/// One camera's files keyed by their view ids ([`view_id`]); a file without a number or two
/// files with the same one is [`CalibError::ViewIds`] naming them.
pub fn camera_files(name: &str, files: &[PathBuf]) -> Result<CameraFiles, CalibError> {
    let err = |message: String| CalibError::ViewIds { camera: name.to_string(), message };
    let no_number: Vec<&Path> =
        files.iter().filter(|f| view_id(f).is_none()).map(PathBuf::as_path).collect();
    if !no_number.is_empty() {
        return Err(err(format!(
            "no shot number in the name of {} ({}); the view id of an image is the last run of digits of its name (ir_0007.png is shot 7): rename the images so that those of one board pose carry the same number in every camera",
            if no_number.len() == 1 {
                "1 file".to_string()
            } else {
                format!("{} files", no_number.len())
            },
            list(&no_number)
        )));
    }
    let mut out = BTreeMap::new();
    for f in files {
        let id = view_id(f).expect("checked above");
        if let Some(first) = out.insert(id, f.clone()) {
            return Err(err(format!(
                "{} and {} carry the same shot number {id}; each image of one camera needs its own shot number (give one of them, or rename it)",
                first.display(),
                f.display()
            )));
        }
    }
    let (role, sensor) = role_of(name);
    Ok(CameraFiles { name: name.to_string(), role, sensor, files: out })
}

/// Fails when two cameras have the same name.
pub fn check_distinct_names<'a>(
    names: impl IntoIterator<Item = &'a str>,
) -> Result<(), CalibError> {
    let mut seen: Vec<&str> = Vec::new();
    for n in names {
        if seen.contains(&n) {
            return Err(CalibError::InvalidArgument(format!(
                "two cameras are called '{n}': give each camera its own name (--camera NAME=GLOB)"
            )));
        }
        seen.push(n);
    }
    Ok(())
}

/// A `--camera NAME=GLOB` argument split at its first `=`: the name (non-empty, without
/// white space or `=`) and the pattern.
pub fn parse_camera_arg(arg: &str) -> Result<(String, String), CalibError> {
    let bad = |why: &str| {
        CalibError::InvalidArgument(format!(
            "--camera '{arg}': {why}; give NAME=GLOB, e.g. --camera 0001.depth='shots/0001/ir_*.png'"
        ))
    };
    let (name, pattern) = arg.split_once('=').ok_or_else(|| bad("no '='"))?;
    let name = name.trim();
    if name.is_empty() || name.chars().any(char::is_whitespace) {
        return Err(bad("the camera's name is empty or has white space"));
    }
    if name.chars().count() > geometry::multi_rig::MAX_NAME_CHARS {
        return Err(bad("the camera's name is too long"));
    }
    if pattern.trim().is_empty() {
        return Err(bad("no image pattern after '='"));
    }
    Ok((name.to_string(), pattern.to_string()))
}

/// The cameras of a multi-sensor capture folder (module docs), in sensor order, each the
/// sorted files of its prefix (`ir_`, `color_`). A folder with no such sub-folder is an
/// error saying what it should hold.
pub fn shots_folder(dir: &Path) -> Result<Vec<(String, Vec<PathBuf>)>, CalibError> {
    let io = |source| CalibError::Io { path: dir.to_path_buf(), source };
    let mut sensors: Vec<PathBuf> = Vec::new();
    for e in std::fs::read_dir(dir).map_err(io)? {
        let p = e.map_err(io)?.path();
        if p.is_dir() {
            sensors.push(p);
        }
    }
    sensors.sort();
    let mut out = Vec::new();
    for s in &sensors {
        let serial = s.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let mut by_prefix: [Vec<PathBuf>; 2] = [Vec::new(), Vec::new()];
        let sio = |source| CalibError::Io { path: s.clone(), source };
        for e in std::fs::read_dir(s).map_err(sio)? {
            let p = e.map_err(sio)?.path();
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            let ext = p.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
            if !p.is_file() || !ext.is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.as_str())) {
                continue;
            }
            for (k, prefix) in ["ir_", "color_"].iter().enumerate() {
                if name.starts_with(prefix) {
                    by_prefix[k].push(p.clone());
                }
            }
        }
        for (files, role) in by_prefix.iter_mut().zip(["depth", "color"]) {
            if !files.is_empty() {
                files.sort();
                out.push((format!("{serial}.{role}"), std::mem::take(files)));
            }
        }
        if out.len() > 2 * MAX_SENSOR_FOLDERS {
            break;
        }
    }
    if out.is_empty() {
        return Err(CalibError::Format {
            path: dir.to_path_buf(),
            message: "no sensor folder with ir_*/color_* images: --shots takes the folder `kfuse capture calib --device all --out DIR` wrote (DIR/SERIAL/ir_0001.png, ...)".into(),
        });
    }
    let folders = out.iter().filter_map(|(n, _)| n.rsplit_once('.')).map(|(s, _)| s);
    let n_folders = folders.collect::<std::collections::BTreeSet<_>>().len();
    if n_folders > MAX_SENSOR_FOLDERS {
        return Err(CalibError::Format {
            path: dir.to_path_buf(),
            message: format!(
                "more than {MAX_SENSOR_FOLDERS} sensor folders with images: not a capture folder of a rig"
            ),
        });
    }
    Ok(out)
}

/// Makes every camera's corner labelling of a view agree with the first camera (input order)
/// that saw that view, as [`crate::detect::align_pair`] does for a Kinect's IR and colour
/// images: on a board whose colouring a half turn leaves unchanged (7x5), each camera picks its
/// labelling by the board's orientation in its image, and two cameras could pick differently
/// for a board near the tie. Like `align_pair` it assumes the cameras are not rolled against
/// each other by more than a few tens of degrees (upright sensors on a ring or a rail).
pub fn align_labels(board: &Board, cameras: &mut [super::CameraViews]) {
    let mut anchor: BTreeMap<u64, ViewCorners> = BTreeMap::new();
    for c in cameras.iter_mut() {
        for (id, v) in c.views.iter_mut() {
            if v.corners.is_empty() {
                continue;
            }
            match anchor.get(id) {
                Some(a) => *v = crate::detect::align_pair(a, v, board),
                None => {
                    anchor.insert(*id, v.clone());
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn view_ids_are_the_last_run_of_digits_of_the_stem() {
        let id = |s: &str| view_id(Path::new(s));
        assert_eq!(id("shots/000000000001/ir_0007.png"), Some(7));
        assert_eq!(id("cam2_shot12.jpg"), Some(12));
        assert_eq!(id("a/b9/ir.png"), None, "the folder's digits do not count");
        assert_eq!(id("ir_12_b.png"), Some(12));
        assert_eq!(id("0000000000000000001.png"), None, "19 digits");
        assert_eq!(id("000000000000000001.png"), Some(1));
    }

    #[test]
    fn camera_files_name_the_offending_files() {
        let p = |v: &[&str]| v.iter().map(PathBuf::from).collect::<Vec<_>>();
        let c = camera_files("a.depth", &p(&["x/ir_2.png", "x/ir_10.png"])).unwrap();
        assert_eq!(c.role, CameraRole::Depth);
        assert_eq!(c.sensor.as_deref(), Some("a"));
        assert_eq!(c.files.keys().copied().collect::<Vec<_>>(), [2, 10]);
        let e = camera_files("a.depth", &p(&["x/ir_7.png", "x/ir_007.png"])).unwrap_err();
        let m = e.to_string();
        assert!(m.contains("x/ir_7.png and x/ir_007.png carry the same shot number 7"), "{m}");
        assert!(m.starts_with("camera a.depth:"), "{m}");
        let e = camera_files("b", &p(&["x/ir_1.png", "x/left.png"])).unwrap_err().to_string();
        assert!(e.contains("no shot number in the name of 1 file (x/left.png)"), "{e}");
    }

    #[test]
    fn roles_and_camera_arguments() {
        assert_eq!(role_of("0001.color"), (CameraRole::Color, Some("0001".into())));
        assert_eq!(role_of("k.ir"), (CameraRole::Depth, Some("k".into())));
        assert_eq!(role_of("left"), (CameraRole::Camera, None));
        assert_eq!(
            parse_camera_arg("a.depth=s/a/ir_*.png").unwrap(),
            ("a.depth".into(), "s/a/ir_*.png".into())
        );
        for bad in ["a.depth", "=x", "a b=x", "a="] {
            let e = parse_camera_arg(bad).unwrap_err().to_string();
            assert!(e.contains("give NAME=GLOB"), "{bad}: {e}");
        }
        let e = check_distinct_names(["a", "b", "a"]).unwrap_err().to_string();
        assert!(e.contains("two cameras are called 'a'"), "{e}");
    }
}
