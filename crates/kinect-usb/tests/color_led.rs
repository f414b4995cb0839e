//! Colour-camera settings (0x3E, protocol §4.10) and the LED API (0x4B, §4.9) end to end over
//! the simulated device: sequence rules (protocol §3.3), round trips, device-side rejection, fault
//! injection. Needs no shared data (synthetic profile).

mod common;

use std::time::Duration;

use kinect_usb::KinectError;
use kinect_usb::backend::UsbBackend;
use kinect_usb::device::{Frame, KinectDevice, State};
use kinect_usb::error::UsbError;
use kinect_usb::protocol::{
    self, ColorSettingCode, Command, Exposure, ExposureMode, LedMode, LedSetting, ep,
};
use kinect_usb::sim::{
    SIM_STATUS_INVALID_VALUE, SIM_STATUS_UNKNOWN_CODE, SimDevice, SimFaults, SimProfile, SimScene,
};

const T: Duration = Duration::from_secs(1);

fn profile() -> SimProfile {
    common::synthetic_profile()
}

fn fake_jpeg(n: usize) -> Vec<u8> {
    let mut j = vec![0xFF, 0xD8];
    j.extend((0..n).map(|i| (i % 97) as u8));
    j.extend([0xFF, 0xD9]);
    j
}

fn sim(faults: SimFaults) -> SimDevice {
    SimDevice::new(
        profile(),
        SimScene { depth_frames: vec![], color_jpegs: vec![fake_jpeg(5_000)] },
        faults,
    )
}

fn started(faults: SimFaults) -> KinectDevice<SimDevice> {
    let mut dev = KinectDevice::open(sim(faults)).unwrap();
    dev.start(true, false).unwrap();
    dev
}

/// The 0x3E / 0x4B lines of the transcript.
fn setting_lines(dev: &KinectDevice<SimDevice>) -> Vec<String> {
    dev.backend()
        .transcript
        .iter()
        .filter(|l| l.starts_with("cmd 0x3e") || l.starts_with("cmd 0x4b seq 0 "))
        .cloned()
        .collect()
}

/// Manual exposure: every 0x3E goes out with sequence 0, the counter is the same before and
/// after, the next normal command carries the counter's value, and GET returns the same f32
/// bits that were set.
#[test]
fn manual_exposure_round_trips_with_sequence_zero() {
    let mut dev = started(SimFaults::default());
    let before = dev.sequence();
    // Start uses sequences 0..=12 on a sensor ready at the second poll (status words 1024, 9729).
    // Protocol §5.2: 0x02 (0), 0x14 (1), serial (2), depth params (3), P0 (4), colour params (5),
    // ModeOn100 (6), ModeOff (7), two status polls (8, 9), 0x09 (10), status (11), 0x2B (12).
    assert_eq!(before, 13);
    dev.set_exposure(Exposure::Manual { integration_ms: 20.5, analog_gain: 2.25 }).unwrap();
    assert_eq!(dev.sequence(), before, "colour settings must not advance the counter");
    assert_eq!(dev.integration_time_ms().unwrap().to_bits(), 20.5f32.to_bits());
    assert_eq!(dev.analog_gain().unwrap().to_bits(), 2.25f32.to_bits());
    assert_eq!(dev.exposure_mode().unwrap(), ExposureMode::Manual);
    assert_eq!(dev.sequence(), before);
    assert_eq!(
        // Protocol §4.10 manual preset (25←0, 0←4, 1←integration ms, 21←analog gain), then
        // the getters 2 (integration time), 22 (analog gain), 80 (exposure mode); sequence 0.
        setting_lines(&dev),
        [
            "cmd 0x3e seq 0 [1, 0, 25, 0]".to_string(),
            "cmd 0x3e seq 0 [1, 0, 0, 4]".into(),
            format!("cmd 0x3e seq 0 [1, 0, 1, {}]", 20.5f32.to_bits()),
            format!("cmd 0x3e seq 0 [1, 0, 21, {}]", 2.25f32.to_bits()),
            "cmd 0x3e seq 0 [1, 0, 2, 0]".into(),
            "cmd 0x3e seq 0 [1, 0, 22, 0]".into(),
            "cmd 0x3e seq 0 [1, 0, 80, 0]".into(),
        ]
    );
    // The next sequenced command continues the counter where start left it.
    dev.command(Command::ReadStatus(protocol::STATUS_REGISTER)).unwrap();
    assert!(
        dev.backend().transcript.last().unwrap().starts_with("cmd 0x16 seq 13 "),
        "{:?}",
        dev.backend().transcript.last()
    );
    // One ordinary command after start's 13 (protocol §3.3: post-incremented counter).
    assert_eq!(dev.sequence(), 14);
    dev.close().unwrap();
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
    assert!(dev.warnings.is_empty(), "{:?}", dev.warnings);
}

#[test]
fn auto_and_semi_auto_presets_and_other_getters() {
    let mut dev = started(SimFaults::default());
    dev.set_exposure(Exposure::Auto { compensation: -1.5 }).unwrap();
    assert_eq!(dev.exposure_mode().unwrap(), ExposureMode::Auto);
    assert_eq!(dev.exposure_compensation().unwrap(), -1.5);
    dev.set_exposure(Exposure::SemiAuto { exposure_ms: 33.0 }).unwrap();
    assert_eq!(dev.exposure_mode().unwrap(), ExposureMode::SemiAuto);
    assert_eq!(dev.exposure_time_ms().unwrap(), 33.0);
    dev.set_rgb_gains(1.5, 1.0, 2.0).unwrap();
    assert_eq!(dev.rgb_gains().unwrap(), [1.5, 1.0, 2.0]);
    dev.set_digital_gain(1.25).unwrap();
    assert_eq!(dev.digital_gain().unwrap(), 1.25);
    dev.set_white_balance_mode(3).unwrap();
    assert_eq!(dev.white_balance_mode().unwrap(), 3);
    dev.set_color_u32(ColorSettingCode::SetFrameRate, 15).unwrap();
    assert_eq!(dev.frame_rate_raw().unwrap(), 15);
    // Start's 13 (protocol §5.2, see manual_exposure_round_trips_with_sequence_zero); 0x3E does
    // not advance it (§3.3).
    assert_eq!(dev.sequence(), 13);
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
}

/// Out-of-range values are refused on the host before anything is sent (named range in the
/// message); values that bypass the typed API are refused by the device's status field.
#[test]
fn bad_values_are_rejected_by_host_and_by_device() {
    let mut dev = started(SimFaults::default());
    let n = dev.backend().transcript.len();
    let e =
        dev.set_exposure(Exposure::Manual { integration_ms: 20.0, analog_gain: 5.0 }).unwrap_err();
    assert!(
        matches!(e, KinectError::Invalid(_))
            // Ranges from protocol §4.10: analog gain f32 1..4, exposure compensation −2..2.
            && e.to_string().contains("analog gain 5 is outside [1, 4]"),
        "{e}"
    );
    let e = dev.set_exposure(Exposure::Auto { compensation: 3.0 }).unwrap_err();
    assert!(e.to_string().contains("compensation 3 is outside [-2, 2]"), "{e}");
    // Each is refused on the host as invalid input (not a USB or protocol failure).
    let invalid = |r: kinect_usb::Result<()>, what: &str| match r {
        Err(KinectError::Invalid(m)) => assert!(m.contains(what), "{m}"),
        other => panic!("expected Invalid naming {what}: {other:?}"),
    };
    invalid(dev.set_rgb_gains(1.0, -1.0, 1.0), "green gain");
    invalid(dev.set_color_f32(ColorSettingCode::GetAnalogGain, 1.0), "GetAnalogGain");
    invalid(dev.set_color_u32(ColorSettingCode::SetAnalogGain, 1), "SetAnalogGain");
    invalid(dev.color_setting(ColorSettingCode::SetMeteringZoneWeight(48), 1).map(|_| ()), "");
    assert_eq!(dev.backend().transcript.len(), n, "nothing may be sent for invalid input");

    // Bypassing host validation: the device answers status ≠ 0 and keeps the old value.
    // libfreenect2 ignores that word; strict_checks makes kfuse reject it.
    dev.strict_checks = true;
    let e = dev.set_color_f32(ColorSettingCode::SetAnalogGain, 8.0).unwrap_err();
    match &e {
        KinectError::Rejected { status, what, .. } => {
            assert_eq!(*status, SIM_STATUS_INVALID_VALUE);
            assert!(what.contains("SetAnalogGain = 8"), "{what}");
        }
        e => panic!("{e}"),
    }
    assert_eq!(dev.analog_gain().unwrap(), 1.0);
    let e = dev.set_color_u32(ColorSettingCode::SetExposureMode, 2).unwrap_err();
    assert!(matches!(e, KinectError::Rejected { status: SIM_STATUS_INVALID_VALUE, .. }), "{e}");
    // A code the protocol document does not list, sent raw.
    let data = dev.command(Command::ColorSetting { code: 5, value: 0 }).unwrap();
    assert_eq!(
        protocol::parse_color_setting_response(&data).unwrap().status,
        SIM_STATUS_UNKNOWN_CODE
    );
    assert_eq!(dev.sequence(), 13);
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
}

/// The simulated colour footer reports the settings: manual integration time and gain appear
/// as the frame's exposure and gain; auto mode reports 10 ms × 2^compensation.
#[test]
fn colour_footer_follows_exposure_settings() {
    let mut dev = started(SimFaults::default());
    let meta = |dev: &mut KinectDevice<SimDevice>| loop {
        match dev.next_frame(T, &mut |_, _| {}).unwrap() {
            Some(Frame::Color(_, m)) => break m,
            Some(_) => continue,
            None => panic!("no colour frame"),
        }
    };
    let m = meta(&mut dev);
    // The simulator's power-on state: auto mode reports SIM_AUTO_EXPOSURE_MS (10 ms) ×
    // 2^compensation (0) with gain 1 (kinect_usb::sim::SimColorSettings); manual reports the set
    // integration time and gain; auto with compensation 1 gives 10 × 2¹ = 20 ms.
    assert_eq!((m.exposure, m.gain), (10.0, 1.0));
    dev.set_exposure(Exposure::Manual { integration_ms: 25.0, analog_gain: 3.0 }).unwrap();
    let m = meta(&mut dev);
    assert_eq!((m.exposure, m.gain), (25.0, 3.0));
    dev.set_exposure(Exposure::Auto { compensation: 1.0 }).unwrap();
    let m = meta(&mut dev);
    assert_eq!((m.exposure, m.gain), (20.0, 1.0));
}

#[test]
fn led_api_uses_sequence_zero_and_is_recorded() {
    let mut dev = started(SimFaults::default());
    let blink = LedSetting::blink(0, 250);
    dev.set_led(blink).unwrap();
    dev.set_led(LedSetting::on(1, 600)).unwrap();
    assert_eq!(dev.sequence(), 13);
    assert_eq!(dev.backend().led(0), Some(blink));
    assert_eq!(
        dev.backend().led(1).map(|l| (l.mode, l.start_level)),
        Some((LedMode::Constant, 600))
    );
    assert_eq!(dev.backend().led_api_log(), &[blink, LedSetting::on(1, 600)]);
    assert_eq!(
        // Protocol §4.9 words: led 0 | blink (1) << 16 = 65536; start 1000 (LED_MAX_LEVEL) |
        // stop 0 << 16 = 1000; interval 250 ms. Then led 1 constant: 600 | 600 << 16.
        setting_lines(&dev),
        [
            "cmd 0x4b seq 0 [65536, 1000, 250, 0]".to_string(),
            format!("cmd 0x4b seq 0 [1, {}, 0, 0]", 600 | (600 << 16))
        ]
    );
    // Invalid settings never leave the host.
    let n = dev.backend().transcript.len();
    assert!(matches!(dev.set_led(LedSetting::on(2, 10)), Err(KinectError::Invalid(_))));
    assert!(matches!(dev.set_led(LedSetting::on(0, 1001)), Err(KinectError::Invalid(_))));
    assert!(matches!(dev.set_led(LedSetting::blink(0, 0)), Err(KinectError::Invalid(_))));
    assert_eq!(dev.backend().transcript.len(), n);
    // Stop and close still number their mode commands from 13 (protocol §5.3/§5.4).
    dev.close().unwrap();
    let tr = &dev.backend().transcript;
    // Stop (protocol §5.3) starts with ModeOn100 = [1, 0x0064_0064 = 6553700, 0, 0] (§4.9) at 13;
    // stop's 8 commands take 13..=20, close's ModeOn100, ModeOff (§5.4) take 21, 22.
    assert!(tr.iter().any(|l| l == "cmd 0x4b seq 13 [1, 6553700, 0, 0]"), "{tr:?}");
    assert!(tr.iter().any(|l| l == "cmd 0x4b seq 22 [0, 0, 0, 0]"), "{tr:?}");
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
    assert!(matches!(dev.set_led(LedSetting::off(0)), Err(KinectError::State { .. })));
    assert_eq!(dev.state(), State::Closed);
}

/// The LED API before start: the device cannot tell it from a first sequenced command, the
/// sim accepts either numbering and start's sequence still begins at 0.
#[test]
fn led_before_start_keeps_start_sequence_at_zero() {
    let mut dev = KinectDevice::open(sim(SimFaults::default())).unwrap();
    dev.set_led(LedSetting::on(0, 1000)).unwrap();
    dev.set_led(LedSetting::off(0)).unwrap();
    dev.start(true, false).unwrap();
    let cmds: Vec<&String> =
        dev.backend().transcript.iter().filter(|l| l.starts_with("cmd")).collect();
    // Protocol §4.9: led 0, constant; start = stop = 1000 packed low half first; LED API at
    // sequence 0 (§3.3); then start's first command 0x02 also at 0 (§5.2).
    assert_eq!(cmds[0], &format!("cmd 0x4b seq 0 [0, {}, 0, 0]", 1000 | (1000 << 16)));
    assert_eq!(cmds[1], "cmd 0x4b seq 0 [0, 0, 0, 0]");
    assert_eq!(cmds[2], "cmd 0x02 seq 0 []");
    assert_eq!(dev.backend().led_api_log().len(), 2);
    assert!(dev.backend().violations.is_empty(), "{:?}", dev.backend().violations);
}

/// The device rejects an invalid LED request through the completion's status word.
#[test]
fn sim_rejects_invalid_led_words_in_completion_status() {
    let mut s = sim(SimFaults::default());
    s.claim(0).unwrap();
    let bad = LedSetting {
        id: 0,
        mode: LedMode::Constant,
        start_level: 2000,
        stop_level: 0,
        interval_ms: 0,
    };
    s.bulk_out(ep::COMMAND_OUT, &Command::Led(bad).encode(0), T).unwrap();
    let mut c = [0u8; 16];
    let n = s.bulk_in(ep::COMMAND_IN, &mut c, T).unwrap();
    assert_eq!(
        protocol::parse_completion_status(&c[..n], "led").unwrap(),
        (0, SIM_STATUS_INVALID_VALUE)
    );
    assert!(s.led_api_log().is_empty());
}

/// Existing fault injection applies to 0x3E: a stall is cleared and the next setting works;
/// a timeout, a premature completion and a short data phase give typed errors.
#[test]
fn command_faults_on_colour_settings() {
    let faults = SimFaults {
        stall_command: Some(0x3E),
        timeout_command: Some(0x3E),
        premature_completion: Some(0x3E),
        short_response: Some(0x3E),
        ..SimFaults::default()
    };
    let mut dev = started(faults);
    let manual = Exposure::Manual { integration_ms: 12.0, analog_gain: 1.5 };
    let e = dev.set_exposure(manual).unwrap_err();
    assert!(matches!(e, KinectError::Usb { source: UsbError::Stall, .. }), "{e}");
    assert!(dev.backend().transcript.iter().any(|l| l == "clear_halt 0x02"));
    let e = dev.set_exposure(manual).unwrap_err();
    assert!(matches!(e, KinectError::Usb { source: UsbError::Timeout, .. }), "{e}");
    let e = dev.set_exposure(manual).unwrap_err();
    assert!(e.to_string().contains("premature completion"), "{e}");
    let e = dev.set_exposure(manual).unwrap_err();
    // The simulator's short_response fault halves the 16-byte response (§4.10) to 8 bytes.
    assert!(e.to_string().contains("short response: 8 bytes, need 16"), "{e}");
    assert_eq!(dev.sequence(), 13);
}

/// Colour settings after an unplug fail with `Disconnected`.
#[test]
fn colour_setting_after_unplug_is_disconnected() {
    let mut dev = started(SimFaults { unplug_after_frames: Some(1), ..SimFaults::default() });
    while dev.next_frame(T, &mut |_, _| {}).is_ok() {}
    let e = dev.set_exposure(Exposure::Auto { compensation: 0.0 }).unwrap_err();
    assert!(matches!(e, KinectError::Disconnected { .. }), "{e}");
}

/// libfreenect2 ignores the 0x3E status word and the LED completion status: by default a
/// non-zero one is counted and noted as a warning and the call succeeds; `strict_checks`
/// turns it into `Rejected`. The device accepts every request here (the setting takes effect)
/// but answers status 7.
#[test]
fn nonzero_status_words_are_counted_not_fatal_unless_strict() {
    let mut dev = started(SimFaults { accepted_status: Some(7), ..SimFaults::default() });
    let warnings0 = dev.warnings.len();
    dev.set_digital_gain(2.0).unwrap();
    assert_eq!(dev.digital_gain().unwrap(), 2.0);
    let led = LedSetting {
        id: 0,
        mode: LedMode::Constant,
        start_level: 500,
        stop_level: 500,
        interval_ms: 0,
    };
    dev.set_led(led).unwrap();
    let c = dev.counters();
    // One SET and one GET 0x3E, one LED API command.
    assert_eq!((c.color_setting_nonzero_status, c.led_nonzero_status), (2, 1));
    let w = &dev.warnings[warnings0..];
    assert_eq!(w.len(), 3, "{w:?}");
    assert!(w.iter().all(|l| l.contains("status 0x7")), "{w:?}");
    assert_eq!(dev.backend().led_api_log(), &[led]);

    dev.strict_checks = true;
    let e = dev.set_digital_gain(1.0).unwrap_err();
    assert!(matches!(e, KinectError::Rejected { status: 7, .. }), "{e}");
    let e = dev.set_led(led).unwrap_err();
    assert!(matches!(e, KinectError::Rejected { status: 7, .. }), "{e}");
    let c = dev.counters();
    assert_eq!((c.color_setting_nonzero_status, c.led_nonzero_status), (3, 2));
    assert_eq!(dev.warnings.len(), warnings0 + 3);
}

/// A colour header magic other than 'BBBB' (libfreenect2 never reads it) is counted and the
/// frame kept; with `strict_checks` every such frame is dropped and counted as dropped too.
#[test]
fn colour_header_magic_is_counted_not_fatal_unless_strict() {
    let mut dev =
        started(SimFaults { color_header_magic: Some(0x4141_4141), ..SimFaults::default() });
    for _ in 0..5 {
        match dev.next_frame(T, &mut |_, _| {}).unwrap() {
            Some(Frame::Color(jpeg, _)) => assert_eq!(jpeg, fake_jpeg(5_000).as_slice()),
            other => panic!("expected a colour frame, got {other:?}"),
        }
    }
    let c = dev.counters();
    assert_eq!((c.color_frames, c.color_bad_header_magic, c.color_dropped), (5, 5, 0));

    dev.strict_checks = true;
    let got = dev.next_frame(Duration::from_millis(200), &mut |_, _| {}).unwrap();
    assert!(got.is_none(), "strict mode must drop every frame");
    let c = dev.counters();
    assert_eq!(c.color_frames, 5);
    assert!(c.color_bad_header_magic > 5, "{c:?}");
    assert_eq!(c.color_dropped, c.color_bad_header_magic - 5, "{c:?}");
}
