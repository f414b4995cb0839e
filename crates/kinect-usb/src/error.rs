//! The crate's single error type.

use std::path::PathBuf;

/// Transport-level failure of one USB operation (mirrors libusb's error classes so callers can
/// say what to do).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum UsbError {
    /// The operation did not finish within its timeout.
    #[error("USB timeout")]
    Timeout,
    /// The endpoint stalled (halt condition).
    #[error("USB endpoint stalled")]
    Stall,
    /// Another process owns the device or interface.
    #[error("device busy (claimed by another program)")]
    Busy,
    /// The device is gone (unplugged or re-enumerated).
    #[error("no device (unplugged?)")]
    NoDevice,
    /// The device sent more data than the buffer holds.
    #[error("USB overflow")]
    Overflow,
    /// Permission denied opening the device node.
    #[error("access denied (udev rule / permissions)")]
    Access,
    /// The kernel refused memory for a transfer (libusb `NO_MEM`, or `ENOMEM` from usbfs):
    /// on Linux usually the `usbfs_memory_mb` limit ([`USBFS_MEMORY_FIX`]).
    #[error("out of memory for USB transfers")]
    NoMem,
    /// Any other I/O error.
    #[error("USB I/O error")]
    Io,
    /// The operation is not supported by this backend or platform.
    #[error("operation not supported")]
    NotSupported,
}

/// What to do when transfers fail for lack of memory: Linux caps the buffers of all programs'
/// USB transfers at `usbfs_memory_mb` (16 MiB by default), and one Kinect v2 streaming depth and
/// colour takes 60 × 8 × 33 792 + 20 × 16 384 bytes (16.5 MB), so a second sensor on the same
/// host (or another USB program) exceeds it.
pub const USBFS_MEMORY_FIX: &str = "Linux limits the memory of all programs' USB transfers to \
    usbfs_memory_mb (16 MiB by default; one Kinect v2 needs about 16 MiB, several sensors on one \
    host exceed it): raise it with `echo 0 | sudo tee /sys/module/usbcore/parameters/usbfs_memory_mb` \
    (0 = no limit, until reboot) or boot with the kernel parameter usbcore.usbfs_memory_mb=1000";

/// Every error of `kinect-usb`.
#[derive(Debug, thiserror::Error)]
pub enum KinectError {
    /// A USB operation failed during `what`.
    #[error("USB error during {what}: {source}")]
    Usb {
        /// What the driver was doing.
        what: String,
        /// The transport error.
        source: UsbError,
    },
    /// Submitting the stream's transfers failed for lack of kernel memory.
    #[error("the kernel refused memory for USB transfers during {what}. {fix}", fix = USBFS_MEMORY_FIX)]
    UsbMemory {
        /// What the driver was doing.
        what: String,
    },
    /// The sensor is in use by another program.
    #[error(
        "device busy: another program (e.g. another kfuse, Protonect, a ROS node) has claimed the Kinect v2; close it and retry"
    )]
    Busy,
    /// No Kinect v2 is connected or visible.
    #[error(
        "no Kinect v2 found. Check: the sensor's power supply is on; it is plugged into a USB 3 (blue, SuperSpeed) port; \
         on Linux a udev rule grants access (e.g. /etc/udev/rules.d/90-kinect2.rules with \
         SUBSYSTEM==\"usb\", ATTR{{idVendor}}==\"045e\", ATTR{{idProduct}}==\"02d8\", MODE=\"0666\"); \
         your user may open /dev/bus/usb/*"
    )]
    NotFound,
    /// USB is not available at all on this machine (no `/dev/bus/usb`, libusb init failed).
    #[error("USB is not available on this machine ({0}); no Kinect v2 can be found")]
    NoUsb(String),
    /// The device was unplugged.
    #[error("the Kinect v2 disappeared (unplugged or lost power) while {what}")]
    Disconnected {
        /// What the driver was doing.
        what: String,
    },
    /// The port reset at open re-enumerated the sensor (libusb `NOT_FOUND`) and no sensor with
    /// the same serial was found again after the wait (protocol §5.1).
    #[error(
        "the Kinect v2 re-enumerated after its USB port reset and no sensor with the same serial \
         came back within {waited_ms} ms (+ 10 open attempts 100 ms apart); unplug and replug it, \
         or try another USB 3 port (some host controllers re-enumerate on every reset)"
    )]
    NotBackAfterReset {
        /// How long the driver waited before looking for it again, ms.
        waited_ms: u64,
    },
    /// The isochronous bandwidth is too small (USB 2 port or a bad hub).
    #[error(
        "insufficient USB bandwidth: endpoint 0x84 offers {got} bytes per interval, need {need}; use a USB 3 port without hubs"
    )]
    InsufficientBandwidth {
        /// Bytes per interval reported by the device.
        got: u32,
        /// Required bytes per interval.
        need: u32,
    },
    /// A protocol rule was violated by the device (or the simulated device by the host).
    #[error("protocol error in {what}: {detail}")]
    Protocol {
        /// The command or stream concerned.
        what: String,
        /// What was wrong.
        detail: String,
    },
    /// A command is not legal in the current session state.
    #[error("{op} is not allowed in state {state}")]
    State {
        /// The operation attempted.
        op: String,
        /// The state the session was in.
        state: String,
    },
    /// A buffer or file had the wrong size.
    #[error("{what}: expected {expected} bytes, got {got}")]
    Size {
        /// What was being read.
        what: String,
        /// Required size.
        expected: usize,
        /// Actual size.
        got: usize,
    },
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A recording file is malformed or truncated.
    #[error("recording {path}: {detail} (at byte {offset})")]
    Recording {
        /// The file.
        path: PathBuf,
        /// Byte offset where the problem was found.
        offset: u64,
        /// What is wrong.
        detail: String,
    },
    /// A USB trace (`.kftrace`) is damaged, or its calls differ from what this kfuse's protocol
    /// code asks.
    #[error(
        "USB trace {path}: {detail} (at byte {offset}); a trace is whole only once its capture \
         ended: record it again with `kfuse capture record --usb-trace FILE`"
    )]
    Trace {
        /// The file.
        path: PathBuf,
        /// Byte offset where the problem was found.
        offset: u64,
        /// What is wrong.
        detail: String,
    },
    /// The stream ended normally (end of a replayed recording).
    #[error("end of stream (recording exhausted)")]
    EndOfStream,
    /// The device answered a setting command with a non-zero status.
    #[error(
        "the Kinect v2 rejected {what}: status {status:#x} ({detail}); check the value against the documented range"
    )]
    Rejected {
        /// The command, with its value.
        what: String,
        /// The status word.
        status: u32,
        /// Where the status came from / the full response.
        detail: String,
    },
    /// Invalid parameter given by the caller.
    #[error("invalid parameter: {0}")]
    Invalid(String),
}

impl KinectError {
    /// Wraps a transport error with context; `NoDevice` becomes [`KinectError::Disconnected`],
    /// `Busy` becomes [`KinectError::Busy`] and `NoMem` [`KinectError::UsbMemory`].
    pub fn usb(what: impl Into<String>, source: UsbError) -> Self {
        match source {
            UsbError::NoDevice => KinectError::Disconnected { what: what.into() },
            UsbError::Busy => KinectError::Busy,
            UsbError::NoMem => KinectError::UsbMemory { what: what.into() },
            _ => KinectError::Usb { what: what.into(), source },
        }
    }
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, KinectError>;
