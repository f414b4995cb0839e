//! One camera's images read and the board detected in them (its size found with `--board
//! auto`), an unreadable image kept as a view that cannot be used, with the reason.

use std::path::{Path, PathBuf};
use std::time::Instant;

use geometry::Image;
use geometry::timing::{Timings, ms_since};

use super::{CameraImages, Event, Observer};
use crate::detect::{Refinement, common_grid_size, detect_views_timed, detect_views_with};
use crate::io::ImageTiming;
use crate::{Board, CalibError, ViewCorners};

/// One camera's views, its images (`None` where unreadable), the board (its size found when
/// `auto`), the stages' times ([`crate::timing::read_stage`], `detect_stage`) and every
/// image's.
pub(super) struct Detected {
    pub views: Vec<ViewCorners>,
    pub images: Vec<Option<Image<u8>>>,
    pub board: Board,
    pub timings: Timings,
    pub image_times: Vec<ImageTiming>,
}

fn file_name(f: &Path) -> String {
    f.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The images of `input` as 8-bit grey with each one's read-and-decode time (0 for images
/// given in memory), progress through `obs`.
fn read(
    input: &CameraImages,
    camera: &str,
    obs: &dyn Observer,
) -> (Vec<Result<Image<u8>, String>>, Vec<f64>) {
    if let Some(decoded) = &input.decoded {
        return decoded.iter().map(|i| (Ok(i.clone()), 0.0)).unzip();
    }
    obs.progress_start(&format!("reading {camera}"), input.files.len());
    let read = crate::io::read_gray_all(&input.files, &|| obs.progress_step())
        .into_iter()
        .map(|(r, ms)| (r.map_err(|e| e.to_string()), ms))
        .unzip();
    obs.progress_end();
    read
}

/// Reads and detects one camera's images. An image that cannot be read is kept as a view that
/// cannot be used, with the reason ([`Event::Unreadable`]), so that the calibration table
/// lists it and goes on.
///
/// With `auto`, the board's size is the complete board most images show. When the board is
/// found in fewer than the views a calibration needs and the images show another size, the
/// error says which.
pub(super) fn load_and_detect(
    input: &CameraImages,
    board: &Board,
    auto: bool,
    camera: &str,
    refinement: Refinement,
    obs: &dyn Observer,
) -> Result<Detected, CalibError> {
    let files: &[PathBuf] = &input.files;
    let mut timings = Timings::new();
    let (images, read_ms) =
        timings.time(&crate::timing::read_stage(camera), || read(input, camera, obs));
    let names: Vec<(String, &Image<u8>)> = files
        .iter()
        .zip(&images)
        .filter_map(|(f, i)| Some((file_name(f), i.as_ref().ok()?)))
        .collect();
    obs.event(Event::Detecting { camera, images: names.len() });
    let mut board = *board;
    let detect_stage = crate::timing::detect_stage(camera);
    if auto {
        let t = Instant::now();
        let size = common_grid_size(&names);
        timings.add(&detect_stage, ms_since(t));
        let Some(((a, b), _)) = size else {
            return Err(CalibError::Input(format!(
                "--board auto: no complete checkerboard found in the {} {camera} image(s); give --board COLSxROWS (inner corners)",
                names.len()
            )));
        };
        (board.cols, board.rows) = (a, b);
    }
    obs.progress_start(&format!("detecting {camera}"), names.len());
    let (found, board, detect_ms) = timings.time(&detect_stage, || {
        detect_views_timed(&names, &board, refinement, &|| obs.progress_step())
    });
    obs.progress_end();
    let with_board = found.iter().filter(|v| !v.corners.is_empty()).count();
    if auto {
        // The count of the views the board was then found in (the ones the calibration
        // uses), not of the images whose whole grid the size search saw.
        obs.event(Event::BoardAuto {
            camera,
            with_board,
            images: names.len(),
            cols: board.cols,
            rows: board.rows,
        });
    }
    if !auto && with_board < crate::mono::MIN_VIEWS {
        let asked = (board.cols.max(board.rows), board.cols.min(board.rows));
        if let Some(((a, b), _)) = common_grid_size(&names).filter(|s| s.0 != asked) {
            // The count of the images the board of that size is then found in (what
            // `--board AxB` would calibrate on), not of those whose whole grid the size search
            // saw: that search can miss boards the detector of a known size finds (partial
            // boards; before it peeled the border's spurious junctions off, OpenCV's 9x6 sample
            // gave 2 of 13 against 13 of 13).
            let suggested = Board { cols: a, rows: b, ..board };
            let (views, _) = detect_views_with(&names, &suggested, refinement, &|| {});
            let n = views.iter().filter(|v| !v.corners.is_empty()).count();
            return Err(CalibError::Input(format!(
                "{camera}: these images show a {a}x{b} grid (found in {n} of {} images); you asked for {}x{} (found in {with_board}). Give --board {a}x{b} (inner corners) or --board auto",
                names.len(),
                board.cols,
                board.rows
            )));
        }
    }
    let mut detect_ms = detect_ms.into_iter();
    let image_times = files
        .iter()
        .zip(&images)
        .zip(read_ms)
        .map(|((f, i), read_ms)| ImageTiming {
            camera: camera.to_string(),
            name: file_name(f),
            read_ms,
            detect_ms: i.as_ref().ok().and_then(|_| detect_ms.next()),
        })
        .collect();
    let mut found = found.into_iter();
    let views = files
        .iter()
        .zip(&images)
        .map(|(f, i)| match i {
            Ok(_) => found.next().expect("one view per readable image"),
            Err(e) => {
                // The reader's message starts with the path, which the line already names.
                let why = e.strip_prefix(&format!("{}: ", f.display())).unwrap_or(e);
                obs.event(Event::Unreadable { path: f, why });
                ViewCorners {
                    name: file_name(f),
                    width: 0,
                    height: 0,
                    corners: vec![],
                    unusable: Some(format!("unreadable: {why}")),
                }
            }
        })
        .collect();
    let images = images.into_iter().map(Result::ok).collect();
    Ok(Detected { views, images, board, timings, image_times })
}

/// One board colouring over several cameras: a board shows the same colouring (which corner
/// square is black) to every camera whose images decide it. Holds the first camera's, and
/// refuses a later camera that decides the other way (images of two sessions).
#[derive(Debug, Default)]
pub(crate) struct Colouring(Option<(bool, String)>);

fn colour_word(black: bool) -> &'static str {
    if black { "black" } else { "white" }
}

impl Colouring {
    /// Notes the colouring `black` that `camera`'s images decide (`None`: they do not);
    /// [`CalibError::Input`] naming both cameras when an earlier one decided the other way.
    pub(crate) fn agree(
        &mut self,
        camera: &str,
        black: Option<bool>,
        board: &Board,
    ) -> Result<(), CalibError> {
        let Some(black) = black else { return Ok(()) };
        match &self.0 {
            Some((first_black, first)) if *first_black != black => Err(CalibError::Input(format!(
                "the {first} images show a {}x{} board whose top-left square is {}, the {camera} images one whose top-left square is {}: not of the same board (images of two sessions?); give the images of one session, or --top-left black|white if the board really is the same",
                board.cols,
                board.rows,
                colour_word(*first_black),
                colour_word(black)
            ))),
            Some(_) => Ok(()),
            None => {
                self.0 = Some((black, camera.to_string()));
                Ok(())
            }
        }
    }
}
