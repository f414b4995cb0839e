//! What `kfuse calibrate` prints while `calib::pipeline` runs: its events as the tables and
//! lines of the command line, its long stages as progress bars.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use calib::pipeline::{Event, Observer};
use indicatif::ProgressBar;

use super::depth::print_fit;
use crate::calibrate_report::{bar, print_held_out, print_mono, print_stereo};

/// Prints the pipeline's events on stdout and its progress on stderr; silent once Ctrl-C or
/// SIGTERM came (the command is stopping, nothing of the run is kept).
#[derive(Default)]
pub(super) struct Printer {
    bar: Mutex<Option<ProgressBar>>,
    /// The current stage is a board detection (the test hook's `calibrate-detect` point).
    detecting: AtomicBool,
}

impl Printer {
    fn with_bar(&self, f: impl FnOnce(&ProgressBar)) {
        if let Ok(b) = self.bar.lock()
            && let Some(b) = b.as_ref()
        {
            f(b);
        }
    }
}

impl Observer for Printer {
    fn progress_start(&self, label: &str, len: usize) {
        self.detecting.store(label.starts_with("detecting"), Ordering::Relaxed);
        if let Ok(mut b) = self.bar.lock() {
            *b = Some(bar(len, label));
        }
    }

    fn progress_step(&self) {
        self.with_bar(|b| b.inc(1));
        if self.detecting.load(Ordering::Relaxed) {
            // The board found in a first image, on the worker thread (test-only hook).
            crate::interrupt::pause_point("calibrate-detect");
        }
    }

    fn progress_end(&self) {
        self.with_bar(ProgressBar::finish);
    }

    fn event(&self, event: Event<'_>) {
        if crate::interrupt::requested() {
            return;
        }
        match event {
            Event::Warning(text) => println!("WARNING: {text}"),
            Event::Detecting { camera, images } => {
                println!("{camera}: detecting the board in {images} image(s)");
            }
            Event::BoardAuto { camera, with_board, images, cols: a, rows: b } => println!(
                "--board auto: {with_board} of {images} {camera} images show a {a}x{b} grid; using {a}x{b}"
            ),
            Event::Unreadable { path, why } => {
                println!("  {}: cannot be read: {why}; left out", path.display());
            }
            Event::Mono { camera, fit, limit_px } => print_mono(camera, fit, limit_px),
            Event::Stereo { fit, ir_views } => print_stereo(fit, ir_views),
            Event::RigWarning(problem) => {
                println!("  WARNING: {problem}; `kfuse fuse` refuses such a rig without --force");
            }
            Event::HeldOut(h) => print_held_out(h),
            Event::DepthNoPose { name, why } => println!("  {name}: {why}; left out"),
            Event::DepthForced(text) => {
                println!("  WARNING (--force): {text}; written anyway (--force)")
            }
            Event::DepthFit(fit) => print_fit(fit),
        }
    }
}
