#![no_main]
//! Command/response parsers must never panic on device bytes.
use kinect_usb::params::{ColorParams, DepthParams, P0Tables};
use kinect_usb::protocol;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = protocol::parse_command(data);
    let _ = protocol::parse_completion(data, "fuzz");
    let _ = protocol::parse_firmware(data);
    let _ = protocol::parse_serial(data);
    let _ = protocol::parse_status(data);
    let _ = protocol::parse_completion_status(data, "fuzz");
    let _ = protocol::parse_color_setting_response(data);
    if data.len() >= 16 {
        let w = |i: usize| u32::from_le_bytes([data[4 * i], data[4 * i + 1], data[4 * i + 2], data[4 * i + 3]]);
        let _ = protocol::LedSetting::from_words([w(0), w(1), w(2), w(3)]);
        if let Some(c) = protocol::ColorSettingCode::from_code(w(0)) {
            let _ = c.value_kind().show(w(1));
            let _ = protocol::Command::ColorSetting { code: c.code(), value: w(1) }.name();
        }
    }
    let _ = DepthParams::from_response(data);
    let _ = ColorParams::from_response(data);
    let _ = P0Tables::from_response(data);
});
