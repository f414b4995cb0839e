#![no_main]
//! Depth assembler: the input is split into packets at the lengths given by its leading bytes.
use kinect_usb::stream::DepthAssembler;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut a = DepthAssembler::new();
    let mut rest = data;
    while rest.len() >= 2 {
        let n = (u16::from_le_bytes([rest[0], rest[1]]) as usize).min(rest.len() - 2);
        let _ = a.push(&rest[2..2 + n]);
        rest = &rest[2 + n..];
    }
});
