//! The one line of noise a successful GPU run printed on headless machines:
//! `error: XDG_RUNTIME_DIR is invalid or not set in the environment.`
//!
//! It comes from libwayland-client, called by Mesa's Vulkan device-select layer (an implicit
//! layer installed with mesa-vulkan-drivers) while the adapters are listed: the layer asks a
//! Wayland compositor which GPU drives the display because wgpu enables the Wayland surface
//! extension on every instance. Without `XDG_RUNTIME_DIR` (ssh sessions, containers, CI)
//! libwayland writes that line to file descriptor 2 itself, and no API reachable without
//! `unsafe` turns it off (the layer's own switch is the `NODEVICE_SELECT=1` environment
//! variable, which the process cannot set for itself safely once threads run).
//!
//! So, only when `XDG_RUNTIME_DIR` is unset or not an absolute path, and only while the
//! instance is created and the adapters listed, file descriptor 2 points at an anonymous
//! temporary file; afterwards it is restored and everything written meanwhile is passed on to
//! stderr except that line. Nothing else is lost or reordered beyond that short window.

use std::io::{Read, Seek, Write};
use std::os::fd::OwnedFd;

/// The start of libwayland's line (older versions: "… not set in the environment.").
const WAYLAND_NOISE: &str = "error: XDG_RUNTIME_DIR";

/// True when libwayland would print its line: `XDG_RUNTIME_DIR` unset or not absolute, and no
/// `WAYLAND_SOCKET` (with one, libwayland does not look at the runtime folder).
fn wayland_would_complain() -> bool {
    let runtime_dir_ok =
        std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_absolute());
    !runtime_dir_ok && std::env::var_os("WAYLAND_SOCKET").is_none()
}

/// Stderr redirected into a temporary file until dropped.
struct Capture {
    saved: OwnedFd,
    file: std::fs::File,
}

impl Capture {
    /// `None` when stderr cannot be redirected (then the line may show; nothing else changes).
    fn start() -> Option<Self> {
        let file = tempfile::tempfile().ok()?;
        let saved = nix::unistd::dup(std::io::stderr()).ok()?;
        nix::unistd::dup2_stderr(&file).ok()?;
        Some(Self { saved, file })
    }
}

impl Drop for Capture {
    fn drop(&mut self) {
        if nix::unistd::dup2_stderr(&self.saved).is_err() {
            return;
        }
        let mut text = String::new();
        if self.file.rewind().is_err() || self.file.read_to_string(&mut text).is_err() {
            return;
        }
        let kept: String =
            text.split_inclusive('\n').filter(|l| !l.starts_with(WAYLAND_NOISE)).collect();
        if !kept.is_empty() {
            let _ = std::io::stderr().write_all(kept.as_bytes());
        }
    }
}

/// Runs `f` (instance creation and adapter listing) without libwayland's line on stderr.
pub(crate) fn without_wayland_noise<T>(f: impl FnOnce() -> T) -> T {
    let _capture = if wayland_would_complain() { Capture::start() } else { None };
    f()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_wayland_line_is_dropped() {
        // What the filter keeps, on the text libwayland and others write.
        let text = "warning: kept\nerror: XDG_RUNTIME_DIR is invalid or not set in the environment.\nerror: XDG_RUNTIME_DIR not set in the environment.\nlast, no newline";
        let kept: String =
            text.split_inclusive('\n').filter(|l| !l.starts_with(WAYLAND_NOISE)).collect();
        assert_eq!(kept, "warning: kept\nlast, no newline");
    }
}
