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
    let _ = DepthParams::from_response(data);
    let _ = ColorParams::from_response(data);
    let _ = P0Tables::from_response(data);
});
