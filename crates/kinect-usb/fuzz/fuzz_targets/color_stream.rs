#![no_main]
//! Colour assembler on arbitrary transfer sequences.
use kinect_usb::stream::ColorAssembler;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut c = ColorAssembler::new();
    let mut rest = data;
    while rest.len() >= 2 {
        let n = (u16::from_le_bytes([rest[0], rest[1]]) as usize).min(rest.len() - 2);
        let _ = c.push(&rest[2..2 + n]);
        rest = &rest[2 + n..];
    }
});
