//! The public corpus (`../shared/data/calib-corpus`, see its README): four real sets from four
//! cameras with OpenCV 5's detections and calibrations in each `reference.json`. Per set and
//! camera, against that reference (every bar asserted where kfuse meets it, else at the
//! measured level, named with the measured value and the reason):
//!
//! * complete boards found ≥ the better of OpenCV's classic and SB detectors
//!   (`boards_found_on_every_set`);
//! * no corner on the negatives (images marked `expected_board: false`; every test, `run_set`);
//! * issue 14's agreed corner bar (`issue_bars_on_every_set`, table `BARS`): where both kfuse
//!   (the complete board) and OpenCV's classic detector found the board, every kfuse corner
//!   within [`CLASSIC5_AGREEMENT_PX`] = 0.5 px (Euclidean) of OpenCV's classic corner refined
//!   with a 5x5 `cornerSubPix` window (`corners_alt`) with the same index, once OpenCV's
//!   corners are turned to kfuse's ordering rule as SB's are (identity or 180°; for boards
//!   whose colour decides, the same turn for every image of the set, since the rule names a
//!   physical corner). Not met on Udacity (0.564 px, and corners where OpenCV's 5x5 corner is
//!   itself off the junction by 7–19 px) and robot-arm (0.541 px);
//! * issue 14's agreed RMS bar (`issue_bars_on_every_set`): per OpenCV calibration recorded
//!   (classic, SB, classic 5x5), on the views both it and kfuse used, kfuse's RMS ≤ OpenCV's,
//!   each the RMS of its own calibration of all its views (kfuse: `calibrate_mono`, k1 k2 p1 p2
//!   k3, no outlier rejection, like `calibrateCamera`) restricted to the shared views by
//!   pooling its per-view errors, sqrt(Σ n_i e_i² / Σ n_i). Not met against SB on Udacity
//!   (0.8640 vs 0.8571 px);
//! * the per-set tests also hold issue 14's first bars at their measured levels: every kfuse
//!   corner within [`SB_AGREEMENT_PX`] of `findChessboardCornersSB`'s corner with the same
//!   index (turned as above), and RMS on all of kfuse's views ≤ the best OpenCV variant.
//!
//! No threshold of the detector was tuned on this corpus (its parameters are those fixed
//! earlier on the lab's IR views and the rendered set). Two rules came from looking at
//! corpus views, neither with a tuned value: the smooth-lines check (GoPro GOPR0053) and the
//! reduced seed basis (OpenCV-set left06 and left12, the only views inspected for it, since
//! replaced by an image test of the same question, issue 29, with every figure here unchanged; the
//! right camera, Udacity, GoPro and robot-arm sets were not looked at and serve as its
//! held-out check: no board lost there, GoPro 32 → 33). The growth's step prediction, its
//! repeated passes and the hole filling (`grid.rs`) came from GoPro GOPR0053 and GOPR0067 only
//! (no tuned value either; GoPro 33 → 35, nothing changed on the other sets).
//! Each test prints its table row; `crates/calib/README.md` holds the table of one run.

mod common;

use std::path::Path;

use calib::detect::detect_views;
use calib::{Board, CalibFlags, Corner, ViewCorners, calibrate_mono};
use common::{f, json, shared_data};
use geometry::Image;
use nalgebra::Vector2;
use serde_json::Value;

/// Issue 14's first corner bar, held by the per-set tests: kfuse's and SB's corners name the
/// same point within 1 px (SB's own error against classic is up to ~0.9 px on these images, see
/// `classic_vs_sb`). Replaced as the issue's bar by [`CLASSIC5_AGREEMENT_PX`], since at the
/// corners where kfuse and SB disagree most SB is the one off (`crates/calib/README.md`'s
/// figure).
const SB_AGREEMENT_PX: f64 = 1.0;

struct Row {
    set: String,
    camera: String,
    images: usize,
    kfuse_found: usize,
    kfuse_partial: usize,
    classic_found: usize,
    sb_found: usize,
    compared: usize,
    worst_px: f64,
    /// Per image where kfuse found the complete board and OpenCV's classic detector found it
    /// too (so `corners_alt` exists): the distance of each kfuse corner (indexed by kfuse's
    /// corner id) from OpenCV's classic corner refined with a 5x5 `cornerSubPix` window
    /// (`corners_alt`) with the same index, once the classic corners are turned to kfuse's
    /// ordering rule exactly as SB's are ([`under_rule`]).
    classic5: Vec<(String, Vec<f64>)>,
    /// The largest of those distances, px.
    worst_classic5_px: f64,
    kfuse_rms: f64,
    /// kfuse's RMS on exactly the views OpenCV's classic calibration used.
    kfuse_rms_same_views: f64,
    /// What `kfuse calibrate` reports with its defaults (outlier rejection on): RMS, corners
    /// and views rejected.
    kfuse_rms_default: (f64, usize, usize),
    opencv_rms: (f64, f64, f64),
    /// The RMS bar's two numbers per OpenCV calibration (classic, SB, classic 5x5), on the
    /// views that calibration and kfuse's both used ([`SharedRms`]).
    shared: Vec<SharedRms>,
}

/// kfuse's and one OpenCV calibration's RMS on the views both used; neither calibration is
/// re-run on those views, each is the full calibration of its own views (kfuse:
/// `calibrate_mono`, k1 k2 p1 p2 k3, no outlier rejection, on every view kfuse detected;
/// OpenCV: the `calibrateCamera` run recorded in `reference.json`), evaluated on the shared
/// views with [`pooled_rms`] of its own per-view errors.
struct SharedRms {
    /// `reference.json`'s name of the OpenCV calibration: `classic`, `sb` or `classic_alt`.
    variant: &'static str,
    /// Views in both: OpenCV's `calibration[camera][variant].views` ∩ the views kfuse used (its
    /// `ViewReport` not rejected).
    views: usize,
    /// [`pooled_rms`] of kfuse's `ViewReport` (`n_corners`, `rms_px`) over the shared views, px.
    kfuse_px: f64,
    /// [`pooled_rms`] of OpenCV's `per_view_rms` over the shared views, with n_i the number
    /// of that variant's corners of the image (the whole board: OpenCV calibrates only
    /// complete boards), px.
    opencv_px: f64,
}

impl Row {
    fn print(&self) {
        let (c, s, a) = self.opencv_rms;
        println!(
            "| {} | {} | {} | {} (+{} partial) | {} / {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} ({} corners out) | {c:.3} / {s:.3} / {a:.3} |",
            self.set,
            self.camera,
            self.images,
            self.kfuse_found,
            self.kfuse_partial,
            self.classic_found,
            self.sb_found,
            self.compared,
            self.worst_px,
            self.worst_classic5_px,
            self.kfuse_rms,
            self.kfuse_rms_same_views,
            self.kfuse_rms_default.0,
            self.kfuse_rms_default.1,
        );
    }
}

fn points(v: &Value) -> Vec<Vector2<f64>> {
    v.as_array().unwrap().iter().map(|p| Vector2::new(f(&p[0]), f(&p[1]))).collect()
}

/// SB's corners of one image in kfuse's labelling under a turn: identity or 180°.
fn turned(sb: &[Vector2<f64>], half_turn: bool) -> Vec<Vector2<f64>> {
    if half_turn { sb.iter().rev().copied().collect() } else { sb.to_vec() }
}

fn worst(view: &ViewCorners, sb: &[Vector2<f64>]) -> f64 {
    view.corners.iter().map(|c| (c.px - sb[c.id]).norm()).fold(0.0, f64::max)
}

/// The distance of each kfuse corner of a complete board from OpenCV's corner with the same
/// index, indexed by corner id.
fn distances(view: &ViewCorners, other: &[Vector2<f64>]) -> Vec<f64> {
    let mut d = vec![f64::NAN; other.len()];
    for c in &view.corners {
        d[c.id] = (c.px - other[c.id]).norm();
    }
    d
}

/// The largest of some distances and its index (NaN for none).
fn max_at(d: &[f64]) -> (f64, usize) {
    d.iter()
        .enumerate()
        .filter(|(_, x)| !x.is_nan())
        .fold((f64::NAN, 0), |a, (i, &x)| if a.0.is_nan() || x > a.0 { (x, i) } else { a })
}

/// OpenCV's corners turned to kfuse's ordering rule, from each image's worst distance with
/// OpenCV's order unturned (`.1`) and turned by 180° (`.2`): where the board's colour decides
/// (one even and one odd square count) one turn for the whole set, the one with the smaller
/// worst distance over the set (the rule names a physical corner, so the turn must not change
/// from image to image); otherwise the turn that the orientation rule picked in each image, the
/// better of the two per image. Returns each image's worst distance under that turn and the set
/// turn (`true`: 180°; meaningful only where colour decides).
fn under_rule<T>(both: &[(String, f64, f64, T)], colour_decides: bool) -> (Vec<f64>, bool) {
    let set_turn = {
        let a = both.iter().map(|b| b.1).fold(0.0, f64::max);
        let b = both.iter().map(|b| b.2).fold(0.0, f64::max);
        b < a
    };
    let per_image = both
        .iter()
        .map(|b| match (colour_decides, set_turn) {
            (true, false) => b.1,
            (true, true) => b.2,
            (false, _) => b.1.min(b.2),
        })
        .collect();
    (per_image, set_turn)
}

/// The RMS over every corner of a set of views from their per-view RMS: sqrt(Σ n_i e_i² / Σ
/// n_i) with n_i corners and RMS e_i in view i (both kfuse's and OpenCV's per-view and overall
/// RMS are sqrt(Σ|e|² / n) over corners, so this is exact; `run_set` checks it reproduces each
/// calibration's own overall RMS on all its views). NaN for no views.
fn pooled_rms(views: impl IntoIterator<Item = (usize, f64)>) -> f64 {
    let (s, n) =
        views.into_iter().fold((0.0, 0), |(s, n), (ni, e)| (s + ni as f64 * e * e, n + ni));
    if n == 0 { f64::NAN } else { (s / n as f64).sqrt() }
}

/// A field of a set's `reference.json` that must be there: a reference without it is a broken
/// corpus, a failure (never a silent early return: issue 52, item 7).
fn field<T>(set: &str, what: &str, v: Option<T>) -> T {
    v.unwrap_or_else(|| panic!("{set}/reference.json: no {what}"))
}

/// Runs `set` for `test`: `None` only where the shared data is absent, with the visible
/// `SKIP <test>` line of `shared_data` (a failure when `KFUSE_REQUIRE_SHARED_DATA=1`); a missing
/// or malformed `reference.json` fails.
fn run_set(test: &str, set: &str) -> Option<Vec<Row>> {
    let root = shared_data(test)?.join("calib-corpus").join(set);
    let r = json(root.join("reference.json"));
    let board = Board::new(
        field(set, "board.cols", r["board"]["cols"].as_u64()) as usize,
        field(set, "board.rows", r["board"]["rows"].as_u64()) as usize,
        1.0,
    )
    .unwrap();
    let colour_decides = (board.cols + board.rows) % 2 == 1;
    let mut rows = Vec::new();
    let cameras = field(set, "cameras object", r["cameras"].as_object());
    assert!(!cameras.is_empty(), "{set}/reference.json: no cameras");
    for (camera, files) in cameras {
        let files: Vec<&str> = field(set, "camera's file list", files.as_array())
            .iter()
            .filter_map(|v| v.as_str())
            .collect();
        assert!(!files.is_empty(), "{set}/reference.json: camera {camera} lists no images");
        let entry = |file: &str| r["images"].as_array().unwrap().iter().find(|i| i["file"] == file);
        let images: Vec<Image<u8>> = files
            .iter()
            .map(|p| calib::io::read_gray(&root.join(p)).unwrap_or_else(|e| panic!("{p}: {e}")))
            .collect();
        let named: Vec<(String, &Image<u8>)> = files
            .iter()
            .zip(&images)
            .map(|(p, i)| (Path::new(p).file_name().unwrap().to_string_lossy().into(), i))
            .collect();
        let (views, _) = detect_views(&named, &board);
        let mut row = Row {
            set: set.into(),
            camera: camera.clone(),
            images: files.len(),
            kfuse_found: 0,
            kfuse_partial: 0,
            classic_found: 0,
            sb_found: 0,
            compared: 0,
            worst_px: 0.0,
            classic5: Vec::new(),
            worst_classic5_px: 0.0,
            kfuse_rms: f64::NAN,
            kfuse_rms_same_views: f64::NAN,
            kfuse_rms_default: (f64::NAN, 0, 0),
            opencv_rms: (f64::NAN, f64::NAN, f64::NAN),
            shared: Vec::new(),
        };
        // Per image: (worst distance with SB unturned, turned 180°).
        let mut both: Vec<(String, f64, f64, ())> = Vec::new();
        // The same against classic 5x5, with every corner's distance in both turns.
        let mut both5: Vec<(String, f64, f64, [Vec<f64>; 2])> = Vec::new();
        for (file, view) in files.iter().zip(&views) {
            let e = entry(file).unwrap();
            let complete = view.corners.len() == board.len();
            if e["expected_board"] == Value::Bool(false) {
                assert!(view.corners.is_empty(), "{set}: a board found in the negative {file}");
                continue;
            }
            row.kfuse_found += complete as usize;
            row.kfuse_partial += (!complete && !view.corners.is_empty()) as usize;
            row.classic_found += (e["classic"]["found"] == Value::Bool(true)) as usize;
            if complete && e["classic"]["found"] == Value::Bool(true) {
                let c5 = points(&e["classic"]["corners_alt"]);
                let d = [distances(view, &turned(&c5, false)), distances(view, &turned(&c5, true))];
                both5.push((file.to_string(), max_at(&d[0]).0, max_at(&d[1]).0, d));
            }
            let sb_found = e["sb"]["found"] == Value::Bool(true);
            row.sb_found += sb_found as usize;
            if sb_found && complete {
                let sb = points(&e["sb"]["corners"]);
                both.push((
                    file.to_string(),
                    worst(view, &turned(&sb, false)),
                    worst(view, &turned(&sb, true)),
                    (),
                ));
            }
        }
        row.compared = both.len();
        let (per_image, set_turn) = under_rule(&both, colour_decides);
        for (b, d) in both.iter().zip(&per_image) {
            println!("  {set} {camera} {}: worst corner vs SB {d:.3} px", b.0);
        }
        if colour_decides {
            println!(
                "  {set} {camera}: SB's corners turned by {} for kfuse's rule",
                if set_turn { "180°" } else { "0°" }
            );
        }
        row.worst_px = per_image.iter().copied().fold(0.0, f64::max);
        let (per_image5, set_turn5) = under_rule(&both5, colour_decides);
        for (b, &d) in both5.iter().zip(&per_image5) {
            // The distances under the turn `under_rule` used for this image.
            let half = if colour_decides { set_turn5 } else { b.2 < b.1 };
            let all = &b.3[half as usize];
            println!(
                "  {set} {camera} {}: worst corner vs classic 5x5 {d:.3} px (#{})",
                b.0,
                max_at(all).1
            );
            row.worst_classic5_px = row.worst_classic5_px.max(d);
            row.classic5.push((b.0.clone(), all.clone()));
        }
        if colour_decides {
            println!(
                "  {set} {camera}: classic 5x5 corners turned by {} for kfuse's rule",
                if set_turn5 { "180°" } else { "0°" }
            );
        }
        let cal = &r["calibration"][camera.as_str()];
        row.opencv_rms =
            (f(&cal["classic"]["rms"]), f(&cal["sb"]["rms"]), f(&cal["classic_alt"]["rms"]));
        let flags = CalibFlags { reject_outliers: false, ..CalibFlags::default() };
        let m = calibrate_mono(camera, &board, &views, &flags, None).expect("calibrates");
        row.kfuse_rms = m.rms_px;
        // The RMS bar: kfuse's calibration `m` and each recorded OpenCV calibration, each
        // evaluated from its own per-view errors on the views both used.
        let kfuse_used: Vec<(&str, usize, f64)> = files
            .iter()
            .zip(&m.views)
            .filter(|(_, v)| v.rejected.is_none())
            .map(|(f, v)| (*f, v.n_corners, v.rms_px))
            .collect();
        let all = pooled_rms(kfuse_used.iter().map(|v| (v.1, v.2)));
        assert!(
            (all - m.rms_px).abs() <= 1e-9 * m.rms_px,
            "{set} {camera}: kfuse's per-view errors pool to {all} px, its RMS is {} px",
            m.rms_px
        );
        for (variant, detector, key) in [
            ("classic", "classic", "corners"),
            ("sb", "sb", "corners"),
            ("classic_alt", "classic", "corners_alt"),
        ] {
            let c = &cal[variant];
            let per_view = c["per_view_rms"].as_object().expect("per_view_rms");
            let n_of = |file: &str| entry(file).unwrap()[detector][key].as_array().unwrap().len();
            let opencv_all = pooled_rms(per_view.iter().map(|(file, e)| (n_of(file), f(e))));
            assert!(
                (opencv_all - f(&c["rms"])).abs() <= 1e-9 * f(&c["rms"]),
                "{set} {camera} {variant}: OpenCV's per-view errors pool to {opencv_all} px, its RMS is {} px",
                f(&c["rms"])
            );
            let shared: Vec<&(&str, usize, f64)> =
                kfuse_used.iter().filter(|v| per_view.contains_key(v.0)).collect();
            let s = SharedRms {
                variant,
                views: shared.len(),
                kfuse_px: pooled_rms(shared.iter().map(|v| (v.1, v.2))),
                opencv_px: pooled_rms(shared.iter().map(|v| (n_of(v.0), f(&per_view[v.0])))),
            };
            println!(
                "  {set} {camera}: on the {} views both kfuse and OpenCV {variant} used: RMS kfuse {:.4} px, OpenCV {variant} {:.4} px",
                s.views, s.kfuse_px, s.opencv_px
            );
            row.shared.push(s);
        }
        // The same views as OpenCV's classic calibration.
        let opencv_views: Vec<&str> = cal["classic"]["views"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_str()).collect())
            .unwrap_or_default();
        let same: Vec<ViewCorners> = files
            .iter()
            .zip(&views)
            .filter(|(f, _)| opencv_views.contains(f))
            .map(|(_, v)| v.clone())
            .collect();
        row.kfuse_rms_same_views =
            calibrate_mono(camera, &board, &same, &flags, None).map_or(f64::NAN, |m| m.rms_px);
        // kfuse's solver on OpenCV's classic 5x5 corners of the same views: how much of the
        // RMS difference is the corners and how much the solver.
        let c5: Vec<ViewCorners> = files
            .iter()
            .zip(&views)
            .filter(|(f, _)| opencv_views.contains(f))
            .map(|(f, v)| {
                let corners = points(&entry(f).unwrap()["classic"]["corners_alt"])
                    .into_iter()
                    .enumerate()
                    .map(|(id, px)| Corner { id, px })
                    .collect();
                ViewCorners { corners, ..v.clone() }
            })
            .collect();
        let c5_rms =
            calibrate_mono(camera, &board, &c5, &flags, None).map_or(f64::NAN, |m| m.rms_px);
        println!(
            "  {set} {camera}: kfuse's solver on OpenCV's classic 5x5 corners: RMS {c5_rms:.4} px (OpenCV {:.4} px)",
            row.opencv_rms.2
        );
        let d = calibrate_mono(camera, &board, &views, &CalibFlags::default(), None)
            .expect("calibrates");
        let rejected_views = d.views.iter().filter(|v| v.rejected.is_some()).count()
            - m.views.iter().filter(|v| v.rejected.is_some()).count();
        row.kfuse_rms_default = (d.rms_px, d.rejected_corners.len(), rejected_views);
        println!(
            "  {set} {camera}: kfuse RMS {:.4} px on all its views, {:.4} px on OpenCV classic's {} views; `kfuse calibrate` defaults (outlier rejection): {:.3} px, {} corners and {} views rejected",
            m.rms_px,
            row.kfuse_rms_same_views,
            same.len(),
            d.rms_px,
            d.rejected_corners.len(),
            rejected_views
        );
        for v in &m.views {
            match &v.rejected {
                Some(why) => println!("  {set} {camera} {}: left out ({why})", v.name),
                None => println!(
                    "  {set} {camera} {}: {} corners, RMS {:.3} px",
                    v.name, v.n_corners, v.rms_px
                ),
            }
        }
        rows.push(row);
    }
    println!(
        "| set | camera | images | kfuse complete boards | OpenCV classic / SB | compared with SB | worst corner vs SB px | worst corner vs classic 5x5 px | kfuse RMS px | kfuse RMS on OpenCV classic's views px | `kfuse calibrate` (outlier rejection) RMS px | OpenCV RMS classic / SB / 5x5 |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for row in &rows {
        row.print();
    }
    Some(rows)
}

/// What a set must show. Issue 14's first bars (boards found ≥ OpenCV's best detector, corners
/// within 1 px of SB's, RMS on all of kfuse's views ≤ OpenCV's best) are asserted where kfuse
/// meets them today; where it does not, the test holds the measured level (so that a regression
/// fails). The agreed bars that replaced the last two are [`issue_bars_on_every_set`]'s.
struct Expect {
    /// Fewest complete boards per camera.
    found: &'static [(&'static str, usize)],
    /// Largest distance of a kfuse corner from SB's corner with the same index (after the
    /// rule's turn), px. A mislabelled corner is a whole square (≥ 10 px here) off.
    sb_px: f64,
    /// RMS ceiling: `None` is the issue's bar (OpenCV's best variant); `Some(px)` holds a
    /// measured level where the bar is not met.
    rms_max: Option<f64>,
}

fn check(rows: &[Row], e: &Expect) {
    for r in rows {
        let want = e.found.iter().find(|f| f.0 == r.camera).map_or(usize::MAX, |f| f.1);
        assert!(
            r.kfuse_found >= want,
            "{} {}: {} complete boards, expected ≥ {want}",
            r.set,
            r.camera,
            r.kfuse_found
        );
        assert!(
            r.worst_px <= e.sb_px,
            "{} {}: a corner {:.3} px from SB's",
            r.set,
            r.camera,
            r.worst_px
        );
        let best_rms = r.opencv_rms.0.min(r.opencv_rms.1).min(r.opencv_rms.2);
        let max = e.rms_max.unwrap_or(best_rms);
        assert!(
            r.kfuse_rms <= max,
            "{} {}: RMS {:.4} px, expected ≤ {max:.4} px (OpenCV's best {best_rms:.4} px)",
            r.set,
            r.camera,
            r.kfuse_rms
        );
    }
}

/// `--board auto`'s size search (`common_grid_size`) on every set and camera: the board's size
/// is the vote's winner, and it sees the whole board in at least as many images as the better
/// of OpenCV's two detectors finds it with the size given (before the partial border lines
/// were peeled off, it saw OpenCV's left 9x6 board in 2 of 13 images). The peeling rule came
/// from the OpenCV set's left images only (its one value, half a line, is not tuned); the right
/// camera and the other three sets were not looked at for it and are its held-out check.
#[test]
fn board_size_search_sees_every_board() {
    let Some(data) = shared_data("board_size_search_sees_every_board") else { return };
    for set in SETS {
        let root = data.join("calib-corpus").join(set);
        let r = json(root.join("reference.json"));
        let (cols, rows) = (
            r["board"]["cols"].as_u64().unwrap() as usize,
            r["board"]["rows"].as_u64().unwrap() as usize,
        );
        for (camera, files) in r["cameras"].as_object().unwrap() {
            let files: Vec<&str> =
                files.as_array().unwrap().iter().filter_map(|v| v.as_str()).collect();
            let images: Vec<Image<u8>> =
                files.iter().map(|p| calib::io::read_gray(&root.join(p)).unwrap()).collect();
            let named: Vec<(String, &Image<u8>)> =
                files.iter().zip(&images).map(|(p, i)| (p.to_string(), i)).collect();
            let found = |key: &str| {
                r["images"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .filter(|i| files.contains(&i["file"].as_str().unwrap_or("")))
                    .filter(|i| i[key]["found"].as_bool() == Some(true))
                    .count()
            };
            let best = found("classic").max(found("sb"));
            let got = calib::detect::common_grid_size(&named);
            println!("  {set} {camera}: size search {got:?}, OpenCV finds the board in {best}");
            let ((a, b), n) = got.unwrap_or_else(|| panic!("{set} {camera}: no size found"));
            assert_eq!((a, b), (cols.max(rows), cols.min(rows)), "{set} {camera}");
            assert!(n >= best, "{set} {camera}: whole board seen in {n}, OpenCV {best}");
        }
    }
}

/// The bar met on every set: complete boards found ≥ the better of OpenCV's two detectors
/// (and, in `run_set`, no board on the negatives).
#[test]
fn boards_found_on_every_set() {
    for set in SETS {
        let Some(rows) = run_set("boards_found_on_every_set", set) else { return };
        for r in rows {
            let best = r.classic_found.max(r.sb_found);
            assert!(
                r.kfuse_found >= best,
                "{} {}: {} boards, OpenCV {best}",
                r.set,
                r.camera,
                r.kfuse_found
            );
        }
    }
}

/// Issue 14's agreed bars on every set and camera (they replace its first bars, corners
/// within [`SB_AGREEMENT_PX`] of SB's and RMS on all of kfuse's views ≤ OpenCV's best, which
/// the per-set tests still hold at their levels; boards found is `boards_found_on_every_set`):
///
/// 1. **Corners**: on every image where kfuse found the complete board and OpenCV's classic
///    detector found it too, every kfuse corner within [`CLASSIC5_AGREEMENT_PX`] of OpenCV's
///    classic corner refined with a 5x5 `cornerSubPix` window (`classic.corners_alt`) with the
///    same index, OpenCV's order turned to kfuse's rule as SB's is ([`under_rule`]: set-wide
///    on the colour-decided 9x6 boards, per image on GoPro's 8x6). The number is
///    [`Row::classic5`]'s per-corner Euclidean distance in pixels, its maximum over the images.
/// 2. **RMS**, per OpenCV calibration recorded (`classic`, `sb`, `classic_alt` = 5x5): on the
///    views both that calibration and kfuse's used, kfuse's RMS ≤ OpenCV's. Both are RMS
///    reprojection errors in px of the calibration each ran on all of its own views, restricted
///    to the shared views through its per-view errors ([`SharedRms`], [`pooled_rms`]:
///    sqrt(Σ n_i e_i² / Σ n_i)): kfuse's is `calibrate_mono` (k1 k2 p1 p2 k3, no outlier
///    rejection) on every view it detected, its `ViewReport`'s `n_corners` and `rms_px`;
///    OpenCV's is `reference.json`'s `per_view_rms` of that `calibrateCamera` run with n_i its
///    corners of the image. `run_set` checks that each side's per-view errors pool to its own
///    overall RMS on all its views.
///
/// Where a bar is not met the table [`BARS`] holds the measured level (a named constant with
/// the measured value and the reason), so that a regression still fails.
#[test]
fn issue_bars_on_every_set() {
    let mut failures = Vec::new();
    let mut table = vec![
        "| set | camera | images compared with classic 5x5 | worst corner vs classic 5x5 px (where) | ceiling px | other corners over the bar: distance px | corners where OpenCV's 5x5 corner is off: distance px (ceiling) | RMS on shared views px, kfuse / OpenCV classic (views) | kfuse / OpenCV SB (views) | kfuse / OpenCV 5x5 (views) |".to_string(),
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |".to_string(),
    ];
    for set in SETS {
        let Some(rows) = run_set("issue_bars_on_every_set", set) else { return };
        for r in rows {
            let who = format!("{} {}", r.set, r.camera);
            let bars = BARS
                .iter()
                .find(|b| b.set == r.set && b.camera == r.camera)
                .unwrap_or_else(|| panic!("{who}: no entry in BARS"));
            if r.classic5.len() != bars.compared {
                failures.push(format!(
                    "{who}: {} images compared with classic 5x5, expected {}",
                    r.classic5.len(),
                    bars.compared
                ));
            }
            // Bar 1, every corner; the corners of `broken` against their own level.
            let mut worst = (0.0, String::new(), 0);
            let mut over = Vec::new();
            for (file, d) in &r.classic5 {
                for (id, &d) in d.iter().enumerate() {
                    let broken = bars.broken.iter().find(|b| b.0 == file && b.1 == id);
                    let max = broken.map_or(bars.classic5_px, |b| b.2);
                    if !(d <= max) {
                        failures.push(format!(
                            "{who} {file} #{id}: {d:.3} px from classic 5x5, expected ≤ {max} px"
                        ));
                    }
                    if broken.is_none() {
                        if d > CLASSIC5_AGREEMENT_PX {
                            over.push(format!("{file} #{id}: {d:.3}"));
                        }
                        if d > worst.0 {
                            worst = (d, file.clone(), id);
                        }
                    }
                }
            }
            let broken: Vec<String> = bars
                .broken
                .iter()
                .map(|(file, id, max)| {
                    let d = r.classic5.iter().find(|c| c.0 == *file).map_or(f64::NAN, |c| c.1[*id]);
                    format!("{file} #{id}: {d:.3} (≤ {max})")
                })
                .collect();
            let mut line = format!(
                "| {} | {} | {} | {:.3} ({} #{}) | {} | {} | {} |",
                r.set,
                r.camera,
                r.classic5.len(),
                worst.0,
                worst.1,
                worst.2,
                bars.classic5_px,
                if over.is_empty() { "none".to_string() } else { over.join("; ") },
                if broken.is_empty() { "none".to_string() } else { broken.join("; ") }
            );
            // Bar 2, per OpenCV calibration.
            for s in &r.shared {
                let level = bars.rms_max.iter().find(|m| m.0 == s.variant).map(|m| m.1);
                let max = level.unwrap_or(s.opencv_px);
                if s.views == 0 || !(s.kfuse_px <= max) {
                    failures.push(format!(
                        "{who}: on the {} views shared with OpenCV {}, RMS kfuse {:.4} px, expected ≤ {max:.4} px (OpenCV {:.4} px)",
                        s.views, s.variant, s.kfuse_px, s.opencv_px
                    ));
                }
                line += &format!(" {:.4} / {:.4} ({}) |", s.kfuse_px, s.opencv_px, s.views);
            }
            table.push(line);
        }
    }
    for line in &table {
        println!("{line}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Issue 14's agreed corner bar: kfuse's corner within 0.5 px of OpenCV's classic corner
/// refined with a 5x5 `cornerSubPix` window.
const CLASSIC5_AGREEMENT_PX: f64 = 0.5;

/// One camera's line of [`issue_bars_on_every_set`].
struct Bars {
    set: &'static str,
    camera: &'static str,
    /// Images compared with classic 5x5: the measured count (no margin, so that the bar cannot
    /// pass by comparing fewer images).
    compared: usize,
    /// Ceiling on every corner's distance from classic 5x5, px: [`CLASSIC5_AGREEMENT_PX`]
    /// (the bar) or a measured level.
    classic5_px: f64,
    /// Corners (image, kfuse corner id, ceiling px) where OpenCV's 5x5 corner is itself off the
    /// junction (`reference.json`: 7–19 px from SB's corner, see [`UDACITY_BROKEN_5X5`]), held at
    /// their own measured level.
    broken: &'static [(&'static str, usize, f64)],
    /// The RMS bar's exceptions: (OpenCV calibration, kfuse's ceiling px) held at a measured
    /// level; every calibration not listed is held to the bar (≤ OpenCV's RMS on the shared
    /// views).
    rms_max: &'static [(&'static str, f64)],
}

const BARS: &[Bars] = &[
    Bars {
        set: SETS[0],
        camera: "left",
        compared: 13,
        classic5_px: CLASSIC5_AGREEMENT_PX,
        broken: &[],
        rms_max: &[],
    },
    Bars {
        set: SETS[0],
        camera: "right",
        compared: 13,
        classic5_px: CLASSIC5_AGREEMENT_PX,
        broken: &[],
        rms_max: &[],
    },
    Bars {
        set: SETS[1],
        camera: "cam",
        compared: 17,
        classic5_px: UDACITY_CLASSIC5_PX,
        broken: UDACITY_BROKEN_5X5,
        rms_max: &[("sb", UDACITY_SB_SHARED_RMS_PX)],
    },
    Bars {
        set: SETS[2],
        camera: "cam",
        compared: 35,
        classic5_px: CLASSIC5_AGREEMENT_PX,
        broken: &[],
        rms_max: &[],
    },
    Bars {
        set: SETS[3],
        camera: "cam",
        compared: 5,
        classic5_px: ROBOTARM_CLASSIC5_PX,
        broken: &[],
        rms_max: &[],
    },
];

/// Udacity, corner bar not met: measured 0.564 px over every corner but
/// [`UDACITY_BROKEN_5X5`]'s, + 0.026 px for estimator changes (a CPU without AVX2 moves corners
/// in the 4th decimal). Two corners are over the bar, both in calibration3, where OpenCV's own
/// corners disagree by as much (`reference.json`): #4 (0.564 px), where 5x5's corner is the one
/// apart, 0.89 px from SB's and 0.80 px from classic 11x11's, which are 0.34 px apart; and #3
/// (0.563 px), where 5x5, 11x11 and SB are 0.33–0.66 px apart from each other (5x5–11x11 0.33,
/// 5x5–SB 0.62, 11x11–SB 0.66). Every kfuse corner of that image is within 0.47 px of SB's.
const UDACITY_CLASSIC5_PX: f64 = 0.59;

/// Udacity: the corners where OpenCV's classic 5x5 corner is off the junction, so the corner
/// bar does not apply, each held at kfuse's measured distance + 0.02–0.03 px (image, corner
/// id, ceiling px). From `reference.json`, per corner (5x5 vs 11x11 / 5x5 vs SB / 11x11 vs
/// SB): calibration15 #27 7.03 / 7.03 / 0.02 px (kfuse measured 7.074 px), #36 7.23 / 7.15 /
/// 0.14 (7.205), #46 10.17 / 10.10 / 0.34 (10.044), #45 0.00 / 19.32 / 19.32 (19.304: the
/// classic corner itself is the corpus README's one stuck at (928, 604) inside a white square,
/// both windows leave it there), calibration17 #0 9.11 / 9.07 / 0.05 (9.116: the README's
/// unrefined corner 9 px off that 5x5 leaves). kfuse is within 0.24 px of SB's corners in
/// both images (the per-set test asserts ≤ 1 px). calibration15 is 1281x721, so no
/// calibration uses it; its board is still compared.
const UDACITY_BROKEN_5X5: &[(&str, usize, f64)] = &[
    ("images/calibration15.jpg", 27, 7.10),
    ("images/calibration15.jpg", 36, 7.23),
    ("images/calibration15.jpg", 45, 19.33),
    ("images/calibration15.jpg", 46, 10.07),
    ("images/calibration17.jpg", 0, 9.14),
];

/// Udacity, RMS bar against SB not met: on the 16 views SB's calibration and kfuse's share,
/// kfuse 0.8640 px against SB's 0.8571 px; the measured 0.8640 + 0.002 px (as the per-set
/// test's RMS level). Met against classic (0.8488 vs 0.8529 px, 15 views) and 5x5 (0.8488 vs
/// 0.9034). Why: kfuse's calibration also fits calibration1 and calibration5, partial boards
/// (47 and 52 corners) at the strongly distorted image border that neither OpenCV detector
/// returns, and the 5-coefficient model fitted to them too sits a little worse on the 16
/// shared views (per view kfuse is above SB on 11 of them, e.g. calibration11 0.723 vs 0.668
/// px). Refitted on exactly SB's 16 views, kfuse gives 0.8556 px (measured once for this
/// note, not asserted), under SB's 0.8571.
const UDACITY_SB_SHARED_RMS_PX: f64 = 0.866;

/// Robot-arm, corner bar not met: measured 0.541 px (05.png #53), + 0.029 px for estimator
/// changes. There too OpenCV's 5x5 corner is the one apart: 0.57 px from SB's and 0.28 px from
/// classic 11x11's (SB and 11x11 0.30 px apart), kfuse within 0.195 px of SB's in that image.
/// It is the only corner over the bar (the test prints those over it).
const ROBOTARM_CLASSIC5_PX: f64 = 0.57;

const SETS: [&str; 4] = [
    "opencv-stereo-640x480-9x6",
    "udacity-camera-cal-1280x720-9x6",
    "gopro-wide-1280x960-8x6",
    "color-1920x1080-9x6-robotarm",
];

/// Measured 2026-12-01 (this branch): left 13, right 13 complete boards (left06 and left12
/// were missed until the seed cell had to be a reduced basis, `grid.rs`, now the image's
/// side test); worst corner vs SB
/// 1.58 / 1.75 px; RMS 0.156 / 0.154 px (OpenCV best 0.195 / 0.207).
///
/// The distance to SB is mostly SB's: at the corners where kfuse is farthest from SB (1.1 to
/// 1.75 px), kfuse is 0.08–0.29 px from OpenCV's classic corner refined with a 5x5
/// `cornerSubPix` window and SB is 0.95–1.92 px from it; over every corner of the 26 images
/// kfuse stays within 0.49 px of that classic corner, which is asserted here within the
/// issue's 1 px (the 11x11-window classic corners are not: the corpus README shows that
/// window pulling corners by up to 7.6 px on this set).
#[test]
fn corpus_opencv_stereo_640x480_9x6() {
    if let Some(rows) = run_set("corpus_opencv_stereo_640x480_9x6", SETS[0]) {
        check(
            &rows,
            // Counts: the measured ones (no margin: one board fewer is a regression). 2.0 px:
            // measured 1.75 + 0.25 px for estimator changes, far below a mislabelling (≥ 10 px).
            &Expect { found: &[("left", 13), ("right", 13)], sb_px: 2.0, rms_max: None },
        );
        for r in &rows {
            assert!(
                r.worst_classic5_px <= SB_AGREEMENT_PX,
                "{} {}: a corner {:.3} px from OpenCV's classic 5x5 corner",
                r.set,
                r.camera,
                r.worst_classic5_px
            );
        }
    }
}

/// Measured: 18 complete boards (OpenCV 17 / 18) + 2 partial, the two 1281x721 images left out,
/// no board on the 3 negatives; worst corner vs SB 0.47 px; RMS 0.863 px (OpenCV 0.853) on
/// kfuse's 18 views, 0.839 px on the 15 views OpenCV's classic calibration used.
#[test]
fn corpus_udacity_1280x720_9x6() {
    if let Some(rows) = run_set("corpus_udacity_1280x720_9x6", SETS[1]) {
        // RMS: the measured 0.863 px + 0.002 px for estimator changes; the issue's bar (0.853)
        // is not met on kfuse's views (README: the three views OpenCV misses add 0.024 px).
        check(
            &rows,
            &Expect { found: &[("cam", 18)], sb_px: SB_AGREEMENT_PX, rms_max: Some(0.865) },
        );
        for r in &rows {
            let best = r.opencv_rms.0.min(r.opencv_rms.1).min(r.opencv_rms.2);
            assert!(
                r.kfuse_rms_same_views <= best,
                "{} {}: RMS on OpenCV's views {:.4} px, OpenCV's best {best:.4} px",
                r.set,
                r.camera,
                r.kfuse_rms_same_views
            );
        }
    }
}

/// Measured: 35 complete boards (OpenCV 35 / 35, the same views) + 0 partial; worst corner vs
/// SB 1.58 px (GOPR0053 corner 47, 0.12 px from classic 5x5: see the README's figure); RMS
/// 0.5230 px (OpenCV 0.8238 / 0.5318 / 0.5233).
#[test]
fn corpus_gopro_wide_1280x960_8x6() {
    if let Some(rows) = run_set("corpus_gopro_wide_1280x960_8x6", SETS[2]) {
        // Counts: measured (no margin). 2.0 px: measured 1.58 + 0.42 px for estimator changes,
        // far below a mislabelling (≥ 10 px); SB is the one off there (README figure). RMS: the
        // issue's bar, at most OpenCV's best (5x5, 0.5233 px).
        check(&rows, &Expect { found: &[("cam", 35)], sb_px: 2.0, rms_max: None });
    }
}

/// Measured: 5 of 5 boards; worst corner vs SB 0.195 px; RMS 0.212 px (OpenCV best 0.234).
#[test]
fn corpus_robotarm_1920x1080_9x6() {
    if let Some(rows) = run_set("corpus_robotarm_1920x1080_9x6", SETS[3]) {
        check(&rows, &Expect { found: &[("cam", 5)], sb_px: SB_AGREEMENT_PX, rms_max: None });
    }
}
