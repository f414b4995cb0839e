//! Property tests of the bit layout and the stream parsers (protocol §14.3).

mod common;

use std::path::Path;

use kinect_usb::KinectError;
use kinect_usb::backend::XferStatus;
use kinect_usb::device::StreamKind;
use kinect_usb::raw::SUB_IMAGE_BYTES;
use kinect_usb::raw::{PIXELS, RAW_FRAME_BYTES, pack_frame, unpack_sub_image};
use kinect_usb::recording::{RecordedEvent, RecordingMeta, RecordingWriter, read_recording};
use kinect_usb::stream::{
    ColorAssembler, ColorMeta, DEPTH_FOOTER_BYTES, DepthAssembler, DepthFooter, build_color_packet,
};
use proptest::prelude::*;

fn frame_with(tag: u8) -> Vec<u8> {
    (0..RAW_FRAME_BYTES).map(|i| ((i * 7 + tag as usize * 13) % 251) as u8).collect()
}

/// Splits each sub-packet of `raw` at the given cut fractions, with `zeros[s]` zero-length
/// packets after sub-packet s.
fn split(
    raw: &[u8],
    seq: u32,
    cuts: &[Vec<f64>],
    zeros: &[usize],
    order: &[usize],
) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for &s in order {
        let mut sub = raw[s * SUB_IMAGE_BYTES..][..SUB_IMAGE_BYTES].to_vec();
        sub.extend_from_slice(
            &DepthFooter {
                timestamp: 7,
                sequence: seq,
                subsequence: s as u32,
                length: SUB_IMAGE_BYTES as u32,
            }
            .to_bytes(),
        );
        let mut pts: Vec<usize> = cuts[s]
            .iter()
            .map(|f| (f * sub.len() as f64) as usize)
            .filter(|&p| p > 0 && p < sub.len())
            .collect();
        pts.sort();
        pts.dedup();
        let mut prev = 0;
        for p in pts.into_iter().chain([sub.len()]) {
            out.push(sub[prev..p].to_vec());
            prev = p;
        }
        out.extend(std::iter::repeat_n(Vec::new(), zeros[s]));
    }
    out
}

proptest! {
    // 12 cases: a run-time choice (each case builds and splits up to three 2 984 960-byte raw
    // frames, protocol §8), not a coverage argument.
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// Any split (each sub-packet ending on a packet boundary), any zero-length packets and any
    /// sub-packet order within a frame reassemble to the original frame.
    #[test]
    fn any_split_reassembles(cuts in prop::collection::vec(prop::collection::vec(0.0f64..1.0, 0..12), 10),
                             zeros in prop::collection::vec(0usize..3, 10),
                             order in Just((0..10).collect::<Vec<usize>>()).prop_shuffle()) {
        let raw = frame_with(3);
        let mut a = DepthAssembler::new();
        let mut got = None;
        for p in split(&raw, 41, &cuts, &zeros, &order) {
            if let Some(f) = a.push(&p) { got = Some((f.sequence, f.data == raw.as_slice())); }
        }
        // 41: the sequence `split` stamped into every footer above.
        prop_assert_eq!(got, Some((41, true)));
    }

    /// Dropping any one non-empty packet of frame 1 drops exactly that frame; frames 0 and 2 survive.
    #[test]
    fn dropping_one_packet_drops_exactly_that_frame(drop_idx in 0usize..200, cut in 0.01f64..0.99) {
        let cuts = vec![vec![cut, 0.5]; 10];
        let zeros = vec![1; 10];
        let order: Vec<usize> = (0..10).collect();
        let raws = [frame_with(0), frame_with(1), frame_with(2)];
        let mut a = DepthAssembler::new();
        let mut seqs = Vec::new();
        for (n, raw) in raws.iter().enumerate() {
            let mut pk = split(raw, n as u32, &cuts, &zeros, &order);
            if n == 1 {
                let nonempty: Vec<usize> = (0..pk.len()).filter(|&i| !pk[i].is_empty()).collect();
                pk.remove(nonempty[drop_idx % nonempty.len()]);
            }
            for p in pk {
                if let Some(f) = a.push(&p) {
                    prop_assert!(f.data == raws[f.sequence as usize].as_slice());
                    seqs.push(f.sequence);
                }
            }
        }
        // Frames 0..3 are sent with sequences 0, 1, 2; frame 1 loses one packet (by construction).
        prop_assert_eq!(seqs, vec![0, 2]);
        // Frame 1 arrived in part: counted once, as incomplete, not also as skipped.
        prop_assert_eq!(a.stats.incomplete_frames, 1);
        prop_assert_eq!(a.stats.skipped_frames, 0);
    }

    /// Colour packets with random JPEG length, 0..3 pad bytes, random filler and random
    /// transfer size parse back to the exact JPEG; a corrupted header magic is counted once and
    /// the frame kept (libfreenect2 does not check it), or, with `strict_header`, drops only
    /// that packet.
    #[test]
    fn color_packets_roundtrip(len in 0usize..5000, pad in 0usize..4, filler in 0usize..300, xfer in 512usize..4096, corrupt in any::<bool>(), strict in any::<bool>()) {
        let mut jpeg = vec![0xFF, 0xD8];
        jpeg.extend((0..len).map(|i| (i % 200) as u8));
        jpeg.extend([0xFF, 0xD9]);
        let meta = |s| ColorMeta { sequence: s, timestamp: 100 + s, exposure: 5.0, gain: 1.25, gamma: 2.0 };
        let mut c = ColorAssembler::new();
        c.strict_header = strict;
        let mut got = Vec::new();
        for s in 0..3u32 {
            let mut p = build_color_packet(&jpeg, &meta(s), pad, filler);
            if corrupt && s == 1 { p[5] ^= 0xFF; }
            for ch in p.chunks(xfer) {
                if let Some((j, m)) = c.push(ch) { got.push((m.sequence, j == jpeg.as_slice(), m == meta(m.sequence))); }
            }
        }
        let want: Vec<(u32, bool, bool)> = (0..3).filter(|&s| !(corrupt && strict && s == 1)).map(|s| (s, true, true)).collect();
        prop_assert_eq!(got, want);
        prop_assert_eq!(c.stats.bad_header_magic, corrupt as u64);
        prop_assert_eq!(c.stats.dropped, (corrupt && strict) as u64);
    }

    /// pack ∘ unpack is the identity on random 11-bit code images.
    #[test]
    fn pack_unpack_roundtrip(seed in any::<u64>()) {
        let mut x = seed | 1;
        let codes: Vec<Vec<u16>> = (0..10).map(|_| (0..PIXELS).map(|_| { x ^= x << 13; x ^= x >> 7; x ^= x << 17; (x & 0x7FF) as u16 }).collect()).collect();
        let mut raw = vec![0u8; RAW_FRAME_BYTES];
        pack_frame(&codes, &mut raw);
        for s in [0usize, 4, 9] {
            prop_assert!(unpack_sub_image(&raw, s) == codes[s]);
        }
    }
}

/// A simulated device with a synthetic profile (no shared data needed).
fn settings_sim() -> kinect_usb::sim::SimDevice {
    use kinect_usb::sim::{SimDevice, SimFaults, SimScene};
    SimDevice::new(common::synthetic_profile(), SimScene::default(), SimFaults::default())
}

proptest! {
    // 48 cases: a run-time choice (up to 24 simulated requests each), not a coverage argument.
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Random 0x3E responses never panic the parser; it accepts exactly the 16-byte answers
    /// that are not a completion, and those round-trip to the same bytes.
    #[test]
    fn color_setting_responses_never_panic(b in prop::collection::vec(any::<u8>(), 0..40), as_completion in any::<bool>()) {
        use kinect_usb::protocol::{encode_completion, is_completion, parse_color_setting_response};
        let b = if as_completion && b.len() >= 4 { encode_completion(b[0] as u32).to_vec() } else { b };
        match parse_color_setting_response(&b) {
            Ok(r) => {
                prop_assert!(b.len() == 16 && !is_completion(&b));
                prop_assert_eq!(r.to_bytes().to_vec(), b);
            }
            Err(_) => prop_assert!(b.len() != 16 || is_completion(&b)),
        }
    }

    /// Random 0x3E requests (any count, sub-sequence, code, value) sent to the simulated device
    /// never panic it, always produce a parseable 16-byte response and a completion with
    /// sequence 0, and an accepted SET is read back bit for bit by its GET code.
    #[test]
    fn sim_answers_random_color_settings(reqs in prop::collection::vec(
        (prop_oneof![Just(1u32), any::<u32>()], prop_oneof![Just(0u32), any::<u32>()], 0u32..100, any::<u32>()), 1..24)) {
        use kinect_usb::backend::UsbBackend;
        use kinect_usb::protocol::{ColorSettingCode, Command, ep, parse_color_setting_response, parse_completion_status};
        use std::time::Duration;
        let t = Duration::from_millis(10);
        let mut s = settings_sim();
        s.claim(0).unwrap();
        let send = |s: &mut kinect_usb::sim::SimDevice, words: [u32; 4]| {
            let mut msg = Command::ColorSetting { code: words[2], value: words[3] }.encode(0);
            for (i, w) in words.iter().enumerate() {
                msg[20 + 4 * i..24 + 4 * i].copy_from_slice(&w.to_le_bytes());
            }
            s.bulk_out(ep::COMMAND_OUT, &msg, t).unwrap();
            let mut data = [0u8; 16];
            let n = s.bulk_in(ep::COMMAND_IN, &mut data, t).unwrap();
            let r = parse_color_setting_response(&data[..n]).unwrap();
            let mut c = [0u8; 16];
            let n = s.bulk_in(ep::COMMAND_IN, &mut c, t).unwrap();
            assert_eq!(parse_completion_status(&c[..n], "0x3E").unwrap().0, 0);
            r
        };
        for (count, sub, code, value) in reqs {
            let r = send(&mut s, [count, sub, code, value]);
            let known = ColorSettingCode::from_code(code);
            if count != 1 || sub != 0 || known.is_none() {
                prop_assert!(r.status != 0);
                continue;
            }
            let c = known.unwrap_or(ColorSettingCode::GetFrameRate);
            if r.status == 0 && !c.is_get() && let Some(get) = (0..100).filter_map(ColorSettingCode::from_code).find(|g| g.set_of_get() == Some(c)) {
                let back = send(&mut s, [1, 0, get.code(), 0]);
                prop_assert_eq!((back.status, back.data), (0, value));
            }
        }
        prop_assert!(s.violations.is_empty(), "{:?}", s.violations);
    }
}

/// A recording of `events` with a small synthetic header.
fn recording_bytes(events: &[RecordedEvent]) -> Vec<u8> {
    let meta = RecordingMeta {
        firmware: "4.0.3912.0".into(),
        serial: "000000000001".into(),
        hardware_info: vec![7; 92],
        depth_params: vec![1; 92],
        p0: vec![2; 64],
        color_params: vec![3; 64],
    };
    let mut w = RecordingWriter::new(Vec::new(), &meta).unwrap();
    for e in events {
        w.write_event(e.kind, &e.to_event()).unwrap();
    }
    w.finish().unwrap()
}

fn event() -> impl Strategy<Value = RecordedEvent> {
    (any::<bool>(), 0u8..4, prop::collection::vec(any::<u8>(), 0..300)).prop_map(|(d, st, data)| {
        let status =
            [XferStatus::Completed, XferStatus::Error, XferStatus::TimedOut, XferStatus::Cancelled]
                [st as usize];
        RecordedEvent { kind: if d { StreamKind::Depth } else { StreamKind::Color }, status, data }
    })
}

proptest! {
    // 256 cases: each is cheap (a few KB), and a bit flip has to land in every part of the
    // format (header fields, record headers, data, checksums, end record) many times.
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// A recording round-trips exactly; any single flipped bit is refused (never replayed as
    /// other data) with a recording error at an offset inside the file, and with
    /// `keep_prefix` at most yields an intact prefix of the original events; any cut is
    /// reported as truncated, and with `keep_prefix` yields an intact prefix.
    #[test]
    fn recordings_roundtrip_and_damage_is_detected(events in prop::collection::vec(event(), 0..20),
                                                   pos in any::<prop::sample::Index>(), bit in 0u8..8) {
        let bytes = recording_bytes(&events);
        let path = Path::new("p.kfrec");
        let r = read_recording(&bytes, path, false).unwrap();
        prop_assert!(r.complete);
        prop_assert_eq!(&r.events, &events);

        let is_prefix = |got: &[RecordedEvent]| got.len() <= events.len() && got == &events[..got.len()];
        let mut flipped = bytes.clone();
        let at = pos.index(bytes.len());
        flipped[at] ^= 1 << bit;
        match read_recording(&flipped, path, false) {
            Err(KinectError::Recording { offset, .. }) => prop_assert!(offset <= bytes.len() as u64),
            other => prop_assert!(false, "flip at {at} bit {bit}: {other:?}"),
        }
        if let Ok(r) = read_recording(&flipped, path, true) {
            prop_assert!(!r.complete && is_prefix(&r.events), "flip at {at}: {} events", r.events.len());
        }

        let cut = &bytes[..at];
        match read_recording(cut, path, false) {
            Err(e @ KinectError::Recording { .. }) => prop_assert!(e.to_string().contains("truncated"), "{e}"),
            other => prop_assert!(false, "cut at {at}: {other:?}"),
        }
        if let Ok(r) = read_recording(cut, path, true) {
            prop_assert!(!r.complete && is_prefix(&r.events));
        }
    }

    /// Random bytes after the magic and version are refused (a recording error at an offset
    /// inside the input), with or without `keep_prefix`: the header checksum cannot match.
    #[test]
    fn random_recording_bytes_are_refused(b in prop::collection::vec(any::<u8>(), 0..400), keep in any::<bool>()) {
        let mut bytes = b"KFUSEREC\x02\0\0\0".to_vec();
        bytes.extend(b);
        match read_recording(&bytes, Path::new("random.kfrec"), keep) {
            Err(KinectError::Recording { offset, .. }) => prop_assert!(offset <= bytes.len() as u64),
            other => prop_assert!(false, "{other:?}"),
        }
    }
}

proptest! {
    // 128 cases of up to 40 packets of up to ~300 KB.
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    /// Random packet sequences never panic either parser, and what they emit is well formed:
    /// depth frames are whole raw frames (10 sub-images, so at most one per 10 packets that
    /// could end a sub-packet) and are all counted; colour frames are JPEGs (FF D8 … FF D9)
    /// shorter than the bytes pushed.
    #[test]
    fn random_packets_never_panic_and_emit_only_whole_frames(pkts in prop::collection::vec(
        prop_oneof![
            Just(0usize), 1usize..200, Just(DEPTH_FOOTER_BYTES), 30_000usize..34_000, 298_000usize..298_700
        ], 0..40), seed in any::<u8>()) {
        let mut a = DepthAssembler::new();
        let mut c = ColorAssembler::new();
        let (mut depth, mut color, mut pushed) = (0u64, 0u64, 0usize);
        let enders = pkts.iter().filter(|&&n| n >= DEPTH_FOOTER_BYTES).count() as u64;
        for (i, n) in pkts.into_iter().enumerate() {
            let p: Vec<u8> = (0..n).map(|k| (k as u8).wrapping_mul(seed).wrapping_add(i as u8)).collect();
            pushed += n;
            if let Some(f) = a.push(&p) {
                prop_assert_eq!(f.data.len(), RAW_FRAME_BYTES);
                depth += 1;
            }
            if let Some((jpeg, _)) = c.push(&p) {
                prop_assert!(jpeg.len() >= 4 && jpeg.len() < pushed);
                prop_assert!(jpeg.starts_with(&[0xFF, 0xD8]) && jpeg.ends_with(&[0xFF, 0xD9]));
                color += 1;
            }
        }
        // Protocol §7: a frame needs 10 sub-packets, each ending on a packet ≥ the 152-byte footer.
        prop_assert!(depth * 10 <= enders, "{depth} frames from {enders} packets");
        prop_assert_eq!(a.stats.frames, depth);
        prop_assert_eq!(c.stats.frames, color);
    }
}
