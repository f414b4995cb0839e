//! `kfuse capture record --usb-trace FILE`: where the trace goes, creating it, and finishing it
//! once the session is closed (or after a failed start, the trace a bug report needs most).

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use kinect_usb::trace::TraceHandle;

/// What `--usb-trace` / `--usb-trace-payload` / `--overwrite` asked for.
pub(super) struct TraceRequest {
    path: Option<PathBuf>,
    payload: bool,
    overwrite: bool,
}

impl TraceRequest {
    pub(super) fn new(path: Option<PathBuf>, payload: bool, overwrite: bool) -> Self {
        TraceRequest { path, payload, overwrite }
    }

    /// Whether `--usb-trace` asked for a trace.
    pub(super) fn requested(&self) -> bool {
        self.path.is_some()
    }

    /// Refuses a trace that would replace the recording or an existing file without
    /// `--overwrite`, or that names a folder.
    pub(super) fn check_path(&self, recording: &Path) -> Result<()> {
        let Some(p) = &self.path else { return Ok(()) };
        if p == recording {
            bail!("--usb-trace {}: is the recording's own file; give another name", p.display());
        }
        if p.is_dir() {
            bail!("--usb-trace {}: is a folder; give a file name such as bug.kftrace", p.display());
        }
        if p.exists() && !self.overwrite {
            bail!("--usb-trace {}: already exists; pass --overwrite to replace it", p.display());
        }
        Ok(())
    }

    /// Starts the trace (written beside its name until it is finished).
    pub(super) fn create(&self) -> Result<Option<TraceHandle>> {
        let Some(p) = &self.path else { return Ok(None) };
        Ok(Some(TraceHandle::create(p, self.payload)?))
    }
}

/// Finishes the trace and says what it holds.
pub(super) fn finish(handle: Option<&TraceHandle>, req: &TraceRequest) -> Result<()> {
    let (Some(h), Some(p)) = (handle, &req.path) else { return Ok(()) };
    let s = h.finish()?;
    let left_out = if s.omitted > 0 {
        format!(", {} later events left out (size bound)", s.omitted)
    } else {
        String::new()
    };
    eprintln!(
        "USB trace: {} records, {} bytes{left_out} in {} (attach it to a bug report; \
         `kfuse replay-trace {}` shows what it holds)",
        s.records,
        s.bytes,
        p.display(),
        p.display()
    );
    Ok(())
}

/// Finishes the trace after the capture failed (the capture's error is the one reported).
pub(super) fn finish_after_error(handle: Option<&TraceHandle>, req: &TraceRequest) {
    if let Err(e) = finish(handle, req) {
        eprintln!("warning: the USB trace could not be written: {e}");
    }
}
