#![no_main]
//! Recording reader on arbitrary bytes (with and without the magic).
use std::path::Path;

use kinect_usb::recording::read_recording;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = read_recording(data, Path::new("fuzz.kfrec"), false);
    let mut b = b"KFUSEREC\x02\0\0\0".to_vec();
    b.extend_from_slice(data);
    let _ = read_recording(&b, Path::new("fuzz.kfrec"), true);
});
