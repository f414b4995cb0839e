//! The wire format byte for byte against protocol §3–§4.

use super::*;

#[test]
fn command_roundtrip_and_lengths() {
    let c = Command::SetMode(MODE_ON_100);
    let m = c.encode(6);
    // Protocol §3.1: a 20-byte header (magic, sequence, max response length, id, 0) plus
    // 4 bytes per parameter word: 36 for 0x4B's four words, 24 for a data page, 20 for none.
    assert_eq!(m.len(), 36);
    let p = parse_command(&m).unwrap();
    assert_eq!((p.sequence, p.id, p.params.clone()), (6, 0x4B, MODE_ON_100.to_vec()));
    assert_eq!(Command::ReadDataPage(2).encode(4).len(), 24);
    assert_eq!(Command::InitStreams.encode(0).len(), 20);
    assert!(parse_command(&m[..30]).is_err());
    let s = encode_serial("016293740947");
    assert_eq!(parse_serial(&s), "016293740947");
    assert_eq!(parse_completion(&encode_completion(9), "x").unwrap(), 9);
}

/// The 20-byte header of a command message with sequence 0, as spelled out in protocol §3.1.
fn header(max_len: u8, id: u8) -> Vec<u8> {
    vec![0x09, 0x20, 0x02, 0x06, 0, 0, 0, 0, max_len, 0, 0, 0, id, 0, 0, 0, 0, 0, 0, 0]
}

/// One 0x3E message `[1, 0, code, value]` with the value given as its 4 little-endian bytes.
fn color_msg(code: u8, value: [u8; 4]) -> Vec<u8> {
    let mut m = header(16, 0x3E);
    m.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0, code, 0, 0, 0]);
    m.extend_from_slice(&value);
    m
}

/// Every preset of protocol §4.10 encodes to the exact bytes: count 1, setting sequence id 0,
/// the code, the value (u32 or the f32 bit pattern, hand-written below: 20.0 = 0x41A00000,
/// 2.0 = 0x40000000, −1.5 = 0xBFC00000, 33.0 = 0x42040000), sequence 0 in the header.
#[test]
fn exposure_presets_encode_byte_for_byte() {
    let enc = |cmds: Vec<Command>| cmds.iter().map(|c| c.encode(0)).collect::<Vec<_>>();
    let acs = color_msg(25, [0, 0, 0, 0]);
    assert_eq!(
        enc(manual_exposure(20.0, 2.0).unwrap()),
        vec![
            acs.clone(),
            color_msg(0, [4, 0, 0, 0]),
            color_msg(1, [0, 0, 0xA0, 0x41]),
            color_msg(21, [0, 0, 0, 0x40])
        ]
    );
    assert_eq!(
        enc(auto_exposure(-1.5).unwrap()),
        vec![acs.clone(), color_msg(0, [0, 0, 0, 0]), color_msg(23, [0, 0, 0xC0, 0xBF])]
    );
    assert_eq!(
        enc(semi_auto_exposure(33.0).unwrap()),
        vec![acs, color_msg(0, [3, 0, 0, 0]), color_msg(17, [0, 0, 0x04, 0x42])]
    );
    for m in enc(manual_exposure(20.0, 2.0).unwrap()) {
        assert_eq!(m.len(), 36);
    }
    // A GET: value word 0, response length 16.
    assert_eq!(Command::get(ColorSettingCode::GetAnalogGain).encode(0), color_msg(22, [0; 4]));
    assert!(Command::get(ColorSettingCode::GetAnalogGain).is_unsequenced());
    assert!(!Command::SetMode(MODE_OFF).is_unsequenced());
}

#[test]
fn exposure_validation_names_the_range() {
    // Out by a little on each side of protocol §4.10's ranges (analog gain 1..4, compensation
    // −2..2) and of (0, MAX_EXPOSURE_MS] for times, plus NaN and infinity.
    for bad in [
        Exposure::Manual { integration_ms: 20.0, analog_gain: 0.5 },
        Exposure::Manual { integration_ms: 20.0, analog_gain: 4.01 },
        Exposure::Manual { integration_ms: 0.0, analog_gain: 2.0 },
        Exposure::Manual { integration_ms: 66.5, analog_gain: 2.0 },
        Exposure::Manual { integration_ms: f32::NAN, analog_gain: 2.0 },
        Exposure::Auto { compensation: 2.5 },
        Exposure::Auto { compensation: -2.01 },
        Exposure::SemiAuto { exposure_ms: -1.0 },
        Exposure::SemiAuto { exposure_ms: f32::INFINITY },
    ] {
        let e = bad.commands().unwrap_err().to_string();
        assert!(e.contains("outside"), "{bad:?}: {e}");
    }
    // Edges of the ranges are accepted.
    assert!(manual_exposure(MAX_EXPOSURE_MS, 4.0).is_ok());
    assert!(manual_exposure(0.1, 1.0).is_ok());
    assert!(auto_exposure(-2.0).is_ok() && auto_exposure(2.0).is_ok());
}

#[test]
fn color_codes_round_trip_and_pair_get_with_set() {
    let mut n = 0;
    for code in 0..=100u32 {
        if let Some(c) = ColorSettingCode::from_code(code) {
            assert_eq!(c.code(), code);
            n += 1;
        }
    }
    // Protocol §4.10 lists codes 0, 1, 2, 10..=83: 3 + 74.
    assert_eq!(n, 77);
    assert_eq!(ColorSettingCode::GetAnalogGain.set_of_get(), Some(ColorSettingCode::SetAnalogGain));
    assert_eq!(
        ColorSettingCode::GetExposureMode.set_of_get(),
        Some(ColorSettingCode::SetExposureMode)
    );
    assert_eq!(ColorSettingCode::GetAnalogGain.value_kind(), ValueKind::F32);
    assert_eq!(ColorSettingCode::GetExposureMode.value_kind(), ValueKind::U32);
    assert_eq!(ColorSettingCode::SetMeteringZoneWeight(47).code(), 76);
}

/// A sample response: num_status 1, command-list status 0, status 0, data = 2.0f32.
#[test]
fn color_setting_response_parses_and_rejects_bad_lengths() {
    let b = [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x40];
    let r = parse_color_setting_response(&b).unwrap();
    assert_eq!(
        r,
        ColorSettingResponse {
            num_status: 1,
            command_list_status: 0,
            status: 0,
            data: 0x4000_0000
        }
    );
    assert_eq!(r.data_f32(), 2.0);
    assert_eq!(r.to_bytes(), b);
    for n in [0, 4, 15, 17] {
        let e = parse_color_setting_response(&vec![0u8; n]).unwrap_err().to_string();
        assert!(e.contains("expected 16 bytes"), "{e}");
    }
    let e = parse_color_setting_response(&encode_completion(0)).unwrap_err().to_string();
    assert!(e.contains("premature completion"), "{e}");
}

/// LED words per protocol §4.9; the start/stop mode words of its table decode as the
/// LED settings it names.
#[test]
fn led_setting_encodes_per_spec() {
    let blink = LedSetting::blink(1, 500);
    // Protocol §4.9: led 1 | blink (1) << 16; start 1000 (0x3E8) | stop 0 << 16; 500 ms; 0.
    // The bad ones break §4.9's ranges: led id 0 or 1, levels 0..1000, blink interval > 0.
    assert_eq!(blink.words(), [0x0001_0001, 0x0000_03E8, 500, 0]);
    let mut m = header(0, 0x4B);
    m.extend_from_slice(&[1, 0, 1, 0, 0xE8, 0x03, 0, 0, 0xF4, 0x01, 0, 0, 0, 0, 0, 0]);
    assert_eq!(Command::Led(blink).encode(0), m);
    assert_eq!(LedSetting::on(1, 100).words(), MODE_ON_100);
    assert_eq!(LedSetting::off(0).words(), MODE_OFF);
    assert_eq!(LedSetting::on(1, 0).words(), MODE_ON);
    assert_eq!(LedSetting::from_words(MODE_ON_100).unwrap(), LedSetting::on(1, 100));
    assert_eq!(LedSetting::from_words(blink.words()).unwrap(), blink);
    for bad in [
        LedSetting::on(2, 100),
        LedSetting::on(0, 1001),
        LedSetting { stop_level: 5000, ..LedSetting::blink(0, 100) },
        LedSetting::blink(0, 0),
    ] {
        assert!(bad.validate().is_err(), "{bad:?}");
        assert!(LedSetting::from_words(bad.words()).is_err(), "{bad:?}");
    }
    assert!(LedSetting::from_words([0x0002_0000, 0, 0, 0]).is_err());
    assert!(LedSetting::from_words([0, 0, 0, 7]).is_err());
}
