//! Ctrl-C and SIGTERM as a flag that long-running commands poll, so that they can finish what
//! must stay valid (a recording's index, a shot's partners) or remove their staging folder
//! before exiting non-zero.
//!
//! The first signal sets the flag; a second one exits at once with status 130 (the shell's
//! convention for "killed by SIGINT"), for a command that does not react. Before it exits, it
//! deletes the temporary files and staging folders of outputs not yet published
//! ([`kfuse_io::atomic::remove_unpublished`]), so that even then only whole outputs are left.
//! (`timeout -s INT` sends its signal to the command and to its process group: two signals
//! at once.)

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Once, OnceLock};

static REQUESTED: AtomicBool = AtomicBool::new(false);
static INSTALLED: OnceLock<Result<(), String>> = OnceLock::new();

/// Exit status of a command stopped by Ctrl-C or SIGTERM (128 + SIGINT).
pub const INTERRUPTED_EXIT_CODE: u8 = 130;

/// Installs the handler (once per process; later calls return the first result).
pub fn install() -> anyhow::Result<()> {
    let result = INSTALLED.get_or_init(|| {
        ctrlc::set_handler(|| {
            if REQUESTED.swap(true, Ordering::SeqCst) {
                let stopped = kfuse_io::atomic::remove_unpublished();
                let removed = match stopped.removed() {
                    0 => String::new(),
                    n => format!("; {n} unfinished output(s) removed, nothing half-written left"),
                };
                eprintln!(
                    "\nerror: interrupted twice (Ctrl-C or SIGTERM): stopped at once{removed}"
                );
                std::process::exit(i32::from(INTERRUPTED_EXIT_CODE));
            }
        })
        .map_err(|e| e.to_string())
    });
    result.clone().map_err(|e| anyhow::anyhow!("cannot install the Ctrl-C handler: {e}"))
}

/// True once Ctrl-C or SIGTERM has been received.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// The error a command returns when it stopped because of a signal.
#[derive(Debug, thiserror::Error)]
#[error("interrupted (Ctrl-C or SIGTERM){0}")]
pub struct Interrupted(pub String);

/// `Err(Interrupted)` once a signal was received, with `what` saying what was kept or removed
/// (e.g. ": the staging folder was removed").
pub fn check(what: &str) -> Result<(), Interrupted> {
    if requested() { Err(Interrupted(what.to_string())) } else { Ok(()) }
}

/// How often [`run_until_interrupted`] looks at the flag: a signal is answered within this
/// (plus the time to exit), far inside the ~1 s a user waits for Ctrl-C to take effect.
const POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Runs `work` on its own thread while this one polls the flag every [`POLL`]: returns its
/// result, or `Err(Interrupted(what))` as soon as Ctrl-C or SIGTERM arrives, without waiting
/// for `work` (it keeps running until the process exits, which the caller then does).
///
/// For stages that write nothing (checkerboard detection, the calibration fits): the library
/// code needs no cancellation points, and a signal is answered within [`POLL`] whatever
/// stage or loop the work is in. A panic in `work` is passed on.
pub fn run_until_interrupted<T: Send + 'static>(
    what: &str,
    work: impl FnOnce() -> T + Send + 'static,
) -> anyhow::Result<T> {
    // The worker says it is done through a channel, so this thread wakes the moment the
    // work ends rather than at the next poll: sleeping in POLL steps cost 25 ms per call on
    // average (73-95 ms of a 0.33-0.38 s stereo run on 15 pairs went to 3 such waits).
    let (done, finished) = std::sync::mpsc::sync_channel::<()>(1);
    let worker = std::thread::Builder::new()
        .name("kfuse-work".into())
        .spawn(move || {
            let value = work();
            // The receiver is gone only when this thread returned Interrupted already.
            let _ = done.send(());
            value
        })
        .map_err(|e| anyhow::anyhow!("cannot start a worker thread: {e}"))?;
    loop {
        check(what)?;
        match finished.recv_timeout(POLL) {
            // Done, or the worker panicked (its sender dropped): join passes the panic on.
            Ok(()) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
        }
    }
    match worker.join() {
        Ok(value) => Ok(value),
        Err(panic) => std::panic::resume_unwind(panic),
    }
}

/// Environment variable naming a point of a command at which it pauses for good (**test-only**:
/// for the tests that must kill or interrupt a run at a known moment,
/// `tests/cli_reliability.rs`; never set it otherwise). On reaching the point the command
/// prints [`PAUSED_MARKER`] and the point's name on its standard output, and the thread waits
/// there until the process ends: killed, or exiting from another thread (a worker paused in
/// [`run_until_interrupted`] leaves the main thread to answer Ctrl-C). Points: `fuse-data`
/// (`fuse`: the cloud and depth images written into the staging folder, the meshes not yet),
/// `fuse-staged` (`fuse`: every output staged, not yet published), `calibrate-detect`
/// (`calibrate`: the board detected in a first image, on the worker thread, so that the
/// detection cannot end before a signal).
pub const PAUSE_AT_ENV: &str = "KFUSE_TEST_PAUSE_AT";

/// The line [`pause_point`] prints (followed by the point's name) when it pauses.
pub const PAUSED_MARKER: &str = "kfuse test hook: paused at";

/// Pauses the calling thread for good when [`PAUSE_AT_ENV`] names `point` (test-only, see
/// there); returns at once otherwise. Reached by several threads, it prints its line once and
/// pauses each of them.
pub fn pause_point(point: &str) {
    if std::env::var_os(PAUSE_AT_ENV).is_none_or(|v| v != point) {
        return;
    }
    static ANNOUNCED: Once = Once::new();
    ANNOUNCED.call_once(|| {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "{PAUSED_MARKER} {point}");
        let _ = out.flush();
    });
    loop {
        // park may return spuriously; the loop keeps the thread here.
        std::thread::park();
    }
}
