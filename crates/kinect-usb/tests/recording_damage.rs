//! Damaged recordings read with `--skip-corrupt --allow-truncated` keep a report of bounded
//! size with exact totals (issue 51: a zero-filled tail added one entry per 10 bytes).

use std::io::Cursor;
use std::path::Path;

use kinect_usb::backend::XferStatus;
use kinect_usb::device::StreamKind;
use kinect_usb::recording::{
    MAX_SKIPPED_RUNS, ReadOptions, RecordedEvent, RecordingMeta, RecordingReader, RecordingWriter,
};

/// Bytes of one record of `n` data bytes: kind, status, length, data, CRC-32.
fn record_bytes(n: usize) -> usize {
    1 + 1 + 4 + n + 4
}

fn meta() -> RecordingMeta {
    RecordingMeta {
        firmware: "4.0.3912.0".into(),
        serial: "000000000001".into(),
        hardware_info: vec![7; 92],
        depth_params: vec![1; 92],
        p0: vec![2; 64],
        color_params: vec![3; 64],
    }
}

/// A recording of `n` depth events of 4 bytes each (`[i; 4]`), with its end record when
/// `finish`; and the header's length.
fn recording(n: usize, finish: bool) -> (Vec<u8>, usize) {
    let header = RecordingWriter::new(Vec::new(), &meta()).unwrap().finish().unwrap().len()
        - record_bytes(8);
    let mut out = Vec::new();
    let mut w = RecordingWriter::new(&mut out, &meta()).unwrap();
    for i in 0..n {
        let ev = RecordedEvent {
            kind: StreamKind::Depth,
            status: XferStatus::Completed,
            data: vec![i as u8; 4],
        };
        w.write_event(ev.kind, &ev.to_event()).unwrap();
    }
    if finish {
        w.finish().unwrap();
    } else {
        w.flush().unwrap();
    }
    (out, header)
}

fn read_all(bytes: &[u8]) -> (Vec<RecordedEvent>, kinect_usb::recording::ReadReport) {
    let opts = ReadOptions { keep_prefix: true, skip_corrupt: true };
    let mut r = RecordingReader::new(Cursor::new(bytes), Path::new("t.kfrec"), opts).unwrap();
    let mut events = Vec::new();
    while let Some(e) = r.next_event().unwrap() {
        events.push(e);
    }
    (events, r.report().clone())
}

/// 8 MiB of zeros after 5 intact records (a file preallocated and cut by a crash): one run of
/// 838 860 ten-byte "records", the last 8 bytes a cut record, every intact event kept.
#[test]
fn a_zero_filled_tail_is_one_run_with_exact_totals() {
    const TAIL: usize = 8 << 20;
    let (mut bytes, header) = recording(5, false);
    let tail_at = bytes.len();
    assert_eq!(tail_at, header + 5 * record_bytes(4));
    bytes.resize(tail_at + TAIL, 0);
    let (events, report) = read_all(&bytes);
    assert_eq!(events.len(), 5);
    assert_eq!(events[4].data, vec![4u8; 4]);
    // A zero record header declares 0 data bytes: 10 bytes each; 8 bytes are left over.
    let whole = (TAIL / record_bytes(0)) as u64;
    assert_eq!(report.skipped_records, whole);
    assert_eq!(report.skipped_bytes, whole * record_bytes(0) as u64);
    assert_eq!(TAIL as u64 - report.skipped_bytes, 8);
    assert_eq!(report.skipped.len(), 1, "{:?}", &report.skipped[..report.skipped.len().min(3)]);
    let run = report.skipped[0];
    assert_eq!((run.first_index, run.offset), (5, tail_at as u64));
    assert_eq!((run.records, run.bytes), (whole, report.skipped_bytes));
    assert_eq!(report.unlisted_runs, 0);
    assert!(report.truncated);
}

/// Every other record corrupt in a recording of 2 200: 1 100 separate runs, the first
/// MAX_SKIPPED_RUNS listed, the rest counted; totals exact, every intact event kept.
#[test]
fn more_damaged_places_than_listed_are_counted() {
    const N: usize = 2200;
    let (mut bytes, header) = recording(N, true);
    let rec = record_bytes(4);
    for i in (0..N).step_by(2) {
        bytes[header + i * rec + 6] ^= 0xff; // a data byte: the checksum no longer matches
    }
    let (events, report) = read_all(&bytes);
    assert_eq!(events.len(), N / 2);
    assert_eq!(events[0].data, vec![1u8; 4]);
    assert_eq!(report.skipped_records, (N / 2) as u64);
    assert_eq!(report.skipped_bytes, (N / 2 * rec) as u64);
    assert_eq!(report.skipped.len(), MAX_SKIPPED_RUNS);
    assert_eq!(report.unlisted_runs, (N / 2 - MAX_SKIPPED_RUNS) as u64);
    let last = report.skipped[MAX_SKIPPED_RUNS - 1];
    let i = 2 * (MAX_SKIPPED_RUNS - 1);
    assert_eq!(last.first_index, i as u64);
    assert_eq!((last.offset, last.records, last.bytes), ((header + i * rec) as u64, 1, rec as u64));
    assert!(!report.truncated);
}
