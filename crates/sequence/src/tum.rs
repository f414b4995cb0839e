//! Export in the TUM RGB-D benchmark's layout (<https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats>):
//! `rgb/` and `depth/` with files named by their timestamp, `rgb.txt` and `depth.txt`
//! (`timestamp filename` per line after three `#` lines), `associations.txt` (`rgb_timestamp
//! rgb_file depth_timestamp depth_file`, the output of the benchmark's `associate.py` that
//! ORB-SLAM's RGB-D examples read) and a README stating units and conventions.
//!
//! Timestamps are the Kinect's own clock in seconds (0.125 ms ticks, exact at six decimals),
//! not Unix time. Depth is the registered depth on the colour grid (the colour camera's z) at
//! [`TUM_UNITS_PER_METRE`] per metre, 0 = no sample; colour is the sensor's JPEG, copied
//! byte for byte.

use std::fmt::Write as _;
use std::path::Path;

use kfuse_io::atomic::write_bytes_atomic;

use crate::Result;
use crate::write::{IndexEntry, TUM_UNITS_PER_METRE};

/// The three header lines of a TUM list file.
fn header(what: &str, source: &str) -> String {
    format!("# {what}\n# file: '{source}' (kfuse sequence export)\n# timestamp filename\n")
}

/// The text of `rgb.txt`, `depth.txt` and `associations.txt` for `frames` (in frame order).
pub fn lists(frames: &[IndexEntry], source: &str) -> (String, String, String) {
    let mut rgb = header("color images", source);
    let mut depth = header("depth maps", source);
    let mut assoc = String::new();
    for f in frames {
        let d = f.files.iter().find(|n| n.starts_with("depth/"));
        let c = f.files.iter().find(|n| n.starts_with("rgb/"));
        let (Some(d), Some(dt)) = (d, &f.depth_time_s) else { continue };
        let _ = writeln!(depth, "{dt} {d}");
        if let (Some(c), Some(ct)) = (c, f.color.as_ref().and_then(|c| c.time_s.as_ref())) {
            let _ = writeln!(rgb, "{ct} {c}");
            let _ = writeln!(assoc, "{ct} {c} {dt} {d}");
        }
    }
    (rgb, depth, assoc)
}

/// The export's README: units, clock, what the depth is.
pub fn readme(source: &str, max_skew_ms: f64) -> String {
    format!(
        "TUM RGB-D layout written by kfuse {version} from {source}\n\
         \n\
         rgb/<t>.jpg       the Kinect v2 colour camera's frame as the scene is (1920x1080; the sensor's mirrored JPEG flipped without loss, as jpegtran -flip horizontal does)\n\
         depth/<t>.png     16-bit depth registered on the colour grid: the colour camera's z of the\n\
         \x20                 nearest depth sample landing on each colour pixel; 0 = no sample\n\
         rgb.txt, depth.txt   'timestamp filename' per line\n\
         associations.txt     'rgb_timestamp rgb_file depth_timestamp depth_file': each depth frame with\n\
         \x20                    the colour frame nearest in time, at most {max_skew_ms:.1} ms apart\n\
         index.json        every frame, every depth frame the recording lost, the run's figures\n\
         \n\
         depth scale: {scale} units per metre (1 unit = 0.2 mm), as the TUM benchmark\n\
         (Open3D: depth_scale=5000; ORB-SLAM: DepthMapFactor: 5000.0)\n\
         timestamps: seconds on the sensor's clock (0.125 ms ticks), not Unix time\n\
         cameras: the colour camera's intrinsics are in the rig used (see index.json's source);\n\
         \x20        depth is in the colour camera's frame and on its pixel grid, distortion included\n",
        version = env!("CARGO_PKG_VERSION"),
        scale = TUM_UNITS_PER_METRE,
    )
}

/// Writes `rgb.txt`, `depth.txt`, `associations.txt` and `README.txt` into `root`.
pub fn write_lists(
    root: &Path,
    frames: &[IndexEntry],
    source: &str,
    max_skew_ms: f64,
) -> Result<()> {
    let (rgb, depth, assoc) = lists(frames, source);
    write_bytes_atomic(&root.join("rgb.txt"), rgb.as_bytes())?;
    write_bytes_atomic(&root.join("depth.txt"), depth.as_bytes())?;
    write_bytes_atomic(&root.join("associations.txt"), assoc.as_bytes())?;
    write_bytes_atomic(&root.join("README.txt"), readme(source, max_skew_ms).as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::write::ColorRef;

    #[test]
    fn lists_pair_only_frames_with_colour_and_keep_frame_order() {
        let entry = |n: u64, dt: &str, ct: Option<&str>| IndexEntry {
            number: n,
            name: None,
            depth_sequence: Some(n as u32),
            depth_time_s: Some(dt.into()),
            depth_time_ticks: None,
            color: ct.map(|t| ColorRef {
                sequence: None,
                time_s: Some(t.into()),
                time_ticks: None,
            }),
            landed: 1,
            files: std::iter::once(format!("depth/{dt}.png"))
                .chain(ct.map(|t| format!("rgb/{t}.jpg")))
                .collect(),
        };
        let frames = vec![entry(0, "1.000000", Some("1.005000")), entry(2, "1.066750", None)];
        let (rgb, depth, assoc) = lists(&frames, "s.kfrec");
        assert_eq!(
            rgb.lines().filter(|l| !l.starts_with('#')).collect::<Vec<_>>(),
            ["1.005000 rgb/1.005000.jpg"]
        );
        assert_eq!(depth.lines().filter(|l| !l.starts_with('#')).count(), 2);
        assert_eq!(assoc, "1.005000 rgb/1.005000.jpg 1.000000 depth/1.000000.png\n");
    }
}
