//! Ctrl-C and SIGTERM as a flag that long-running commands poll, so that they can finish what
//! must stay valid (a recording's index, a shot's partners) or remove their staging folder
//! before exiting non-zero.
//!
//! The first signal sets the flag; a second one exits at once with status 130 (the shell's
//! convention for "killed by SIGINT"), for a command that does not react.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);
static INSTALLED: OnceLock<Result<(), String>> = OnceLock::new();

/// Exit status of a command stopped by Ctrl-C or SIGTERM (128 + SIGINT).
pub const INTERRUPTED_EXIT_CODE: u8 = 130;

/// Installs the handler (once per process; later calls return the first result).
pub fn install() -> anyhow::Result<()> {
    let result = INSTALLED.get_or_init(|| {
        ctrlc::set_handler(|| {
            if REQUESTED.swap(true, Ordering::SeqCst) {
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
