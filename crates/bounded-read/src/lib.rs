//! The one way kfuse reads a whole file into memory: at most a limit of bytes, whatever the
//! file is. A size check on the file's stated length alone lets devices and pipes through
//! (`/dev/zero`, `/dev/urandom`, a FIFO, `/dev/stdin` state a length of 0) and then reads
//! them to the end, that is for ever or until memory runs out. [`read_bounded`] reads through
//! [`Read::take`] at most `limit + 1` bytes, so a source longer than the limit is an error
//! after `limit + 1` bytes at most, whichever kind of file it is.
//!
//! The error is a [`std::io::Error`] of kind [`ErrorKind::FileTooLarge`] whose message says
//! the limit, what the file was expected to be and the fix; every crate wraps it in its own
//! error that names the file (`path: message`), so the user sees one line.

#![deny(missing_docs)]

use std::io::{ErrorKind, Read};
use std::path::Path;

/// What a bounded read expects the file to be, for the message of a too-large file.
#[derive(Debug, Clone, Copy)]
pub struct Expected<'a> {
    /// The kind of file, with its article: "a calibration file", "an image file".
    pub what: &'a str,
    /// The fix, a phrase: "is this the right file?", "give the rig file kfuse calibrate wrote".
    pub fix: &'a str,
}

/// The message of a file over its limit (the caller's error adds the path in front).
fn too_large(limit: u64, stated: Option<u64>, expected: Expected<'_>) -> std::io::Error {
    let (what, fix) = (expected.what, expected.fix);
    let message = match stated {
        Some(n) => format!("is {n} bytes, over the {limit}-byte limit for {what}; {fix}"),
        None => format!(
            "gave more than {limit} bytes, the limit for {what} (a device or a pipe? reading stopped there); {fix}"
        ),
    };
    std::io::Error::new(ErrorKind::FileTooLarge, message)
}

/// Reads all of `path`, at most `limit` bytes: a regular file that states a larger size fails
/// before anything is read, and any other source (device, pipe, FIFO, a file that grows) after
/// `limit + 1` bytes at most. Errors are [`std::io::Error`]s without the path (the caller's
/// error names the file); one over the limit has kind [`ErrorKind::FileTooLarge`].
pub fn read_bounded(path: &Path, limit: u64, expected: Expected<'_>) -> std::io::Result<Vec<u8>> {
    read_bounded_from(open_bounded(path, limit, expected)?, limit, expected)
}

/// Opens `path` for a bounded read: refuses a folder, and a regular file that states more than
/// `limit` bytes. Read the file with [`read_bounded_from`] and the same limit (a caller that
/// looks at the first bytes before reading on, as the image reader does, chains them back).
pub fn open_bounded(
    path: &Path,
    limit: u64,
    expected: Expected<'_>,
) -> std::io::Result<std::fs::File> {
    let file = open_without_blocking(path)?;
    let meta = file.metadata()?;
    if meta.is_dir() {
        return Err(std::io::Error::new(
            ErrorKind::IsADirectory,
            format!("is a folder, not {}", expected.what),
        ));
    }
    if meta.is_file() && meta.len() > limit {
        return Err(too_large(limit, Some(meta.len()), expected));
    }
    Ok(file)
}

/// Longest wait for a program to write to a named pipe (FIFO) given as a file: 10 s. A FIFO
/// nobody writes to blocked `open(2)` for ever, beyond the reach of Ctrl-C's flag and of
/// Python's signal handling; a program that feeds a FIFO is started with the command or
/// before it, and writes within moments.
pub const FIFO_WRITER_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// Opens `path` for reading without blocking for ever on a named pipe (FIFO) that nobody
/// writes to: a FIFO is opened with `O_NONBLOCK` (which returns at once), then waited on with
/// `poll(2)` for at most [`FIFO_WRITER_WAIT`] until its writer has written (an error of kind
/// [`ErrorKind::TimedOut`] otherwise), and set back to blocking reads. Any other file is opened
/// as [`std::fs::File::open`] does. `stat(2)` of the path, which tells a FIFO, never blocks.
pub fn open_without_blocking(path: &Path) -> std::io::Result<std::fs::File> {
    open_waiting(path, FIFO_WRITER_WAIT)
}

fn open_waiting(path: &Path, wait: std::time::Duration) -> std::io::Result<std::fs::File> {
    use nix::fcntl::{FcntlArg, OFlag, fcntl};
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    use std::os::fd::AsFd;
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    if !std::fs::metadata(path)?.file_type().is_fifo() {
        return std::fs::File::open(path);
    }
    let file =
        std::fs::OpenOptions::new().read(true).custom_flags(OFlag::O_NONBLOCK.bits()).open(path)?;
    // Until a writer has come, Linux reports neither POLLIN nor POLLHUP for a reader opened
    // without blocking: poll waits for the writer's first bytes (or its close).
    let timeout = PollTimeout::try_from(wait).unwrap_or(PollTimeout::MAX);
    let mut fds = [PollFd::new(file.as_fd(), PollFlags::POLLIN)];
    if poll(&mut fds, timeout)? == 0 {
        return Err(std::io::Error::new(
            ErrorKind::TimedOut,
            format!(
                "is a named pipe (FIFO) that no program wrote to within {} s; give a regular file, or start the program that writes to it first",
                wait.as_secs_f64()
            ),
        ));
    }
    let flags = OFlag::from_bits_truncate(fcntl(&file, FcntlArg::F_GETFL)?);
    fcntl(&file, FcntlArg::F_SETFL(flags - OFlag::O_NONBLOCK))?;
    Ok(file)
}

/// [`read_bounded`] of an open reader: at most `limit + 1` bytes are read, more than `limit`
/// is an error of kind [`ErrorKind::FileTooLarge`].
pub fn read_bounded_from<R: Read>(
    reader: R,
    limit: u64,
    expected: Expected<'_>,
) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::new();
    reader.take(limit.saturating_add(1)).read_to_end(&mut out)?;
    if out.len() as u64 > limit {
        return Err(too_large(limit, None, expected));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXPECTED: Expected<'static> =
        Expected { what: "a test file", fix: "is this the right file?" };

    #[test]
    fn dev_zero_stops_after_the_limit() {
        let e = read_bounded(Path::new("/dev/zero"), 1000, EXPECTED).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::FileTooLarge);
        let m = e.to_string();
        assert!(m.contains("more than 1000 bytes") && m.contains("a test file"), "{m}");
        assert!(m.contains("is this the right file?"), "{m}");
    }

    #[test]
    fn a_reader_is_read_at_most_limit_plus_one() {
        // An endless reader counting what it gave: exactly limit + 1 bytes are taken.
        struct Endless(u64);
        impl Read for Endless {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                self.0 += buf.len() as u64;
                Ok(buf.len())
            }
        }
        let mut src = Endless(0);
        let e = read_bounded_from(&mut src, 4096, EXPECTED).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::FileTooLarge);
        assert_eq!(src.0, 4097, "bytes pulled from the endless source");
    }

    #[test]
    fn files_at_and_over_the_limit() {
        let dir = std::env::temp_dir().join(format!("kfuse-bounded-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("x.bin");
        std::fs::write(&f, [7u8; 100]).unwrap();
        assert_eq!(read_bounded(&f, 100, EXPECTED).unwrap(), vec![7u8; 100]);
        let e = read_bounded(&f, 99, EXPECTED).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::FileTooLarge);
        assert!(e.to_string().starts_with("is 100 bytes, over the 99-byte limit"), "{e}");
        let e = read_bounded(&dir, 99, EXPECTED).unwrap_err();
        assert_eq!(e.kind(), ErrorKind::IsADirectory);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A FIFO nobody writes to: opening it must not wait for a writer for ever (it blocked
    /// `open(2)`, and Ctrl-C could not stop it): an error of kind TimedOut after the wait. A
    /// writer that comes after the reader (the race of a feeding program started alongside)
    /// and one that is there first are both read, bounded as any pipe.
    #[test]
    fn a_fifo_without_a_writer_does_not_block() {
        let dir = std::env::temp_dir().join(format!("kfuse-bounded-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("rig.json");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
        assert!(made.success(), "mkfifo failed");
        let wait = std::time::Duration::from_millis(300);
        let (tx, rx) = std::sync::mpsc::channel();
        let path = fifo.clone();
        std::thread::spawn(move || tx.send(open_waiting(&path, wait).map(|_| ())));
        let got = rx.recv_timeout(std::time::Duration::from_secs(10));
        let err = got.expect("blocked on a FIFO without a writer").unwrap_err();
        assert_eq!(err.kind(), ErrorKind::TimedOut);
        assert!(err.to_string().contains("no program wrote to within 0.3 s"), "{err}");

        for writer_first in [false, true] {
            let path = fifo.clone();
            let writer = std::thread::spawn(move || {
                if !writer_first {
                    std::thread::sleep(std::time::Duration::from_millis(200));
                }
                std::fs::write(&path, [5u8; 300]).unwrap()
            });
            if writer_first {
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
            let bytes = read_bounded(&fifo, 1000, EXPECTED).unwrap();
            writer.join().unwrap();
            assert_eq!(bytes, vec![5u8; 300], "writer first: {writer_first}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
