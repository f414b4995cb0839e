//! The exact bytes the colour-setting methods put on the wire, pinned to the tables of the
//! repository's protocol document (`docs/kinect-v2-protocol.md`): §3.1 (the command message:
//! magic `0x06022009`, sequence, max response length, command id, 0, parameters) and §4.10
//! (`0x3E`, parameters `[1, 0, code, value]`, sequence 0, 16-byte response; codes 10 white
//! balance, 11/12/13 set red/green/blue gain, 14/15/16 get them, 19/20 set/get digital gain,
//! 81 get white balance, 82/83 set/get frame rate). The bytes are written out here by hand;
//! they are captured from the backend before the simulated device sees them, so this test does
//! not depend on the simulator's (or the crate's) own idea of the codes.

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use kinect_usb::backend::{
    EventSink, ResetOutcome, Serviced, StreamHandle, StreamSpec, UsbBackend,
};
use kinect_usb::device::KinectDevice;
use kinect_usb::error::UsbError;
use kinect_usb::protocol::ColorSettingCode;
use kinect_usb::sim::{SimDevice, SimFaults, SimScene};

/// Forwards everything to the simulated device and keeps a copy of every command message
/// written to endpoint 0x02.
struct Spy {
    inner: SimDevice,
    sent: Arc<Mutex<Vec<Vec<u8>>>>,
}

impl UsbBackend for Spy {
    fn active_config(&mut self) -> Result<u8, UsbError> {
        self.inner.active_config()
    }
    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError> {
        self.inner.set_config(cfg)
    }
    fn reset(&mut self) -> Result<ResetOutcome, UsbError> {
        self.inner.reset()
    }
    fn reopen(&mut self, wait: std::time::Duration) -> Result<(), UsbError> {
        self.inner.reopen(wait)
    }
    fn claim(&mut self, iface: u8) -> Result<(), UsbError> {
        self.inner.claim(iface)
    }
    fn release(&mut self, iface: u8) -> Result<(), UsbError> {
        self.inner.release(iface)
    }
    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError> {
        self.inner.set_alt(iface, alt)
    }
    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        data: &[u8],
        timeout: Duration,
    ) -> Result<usize, UsbError> {
        self.inner.control_out(req_type, req, value, index, data, timeout)
    }
    fn bulk_out(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<usize, UsbError> {
        if ep == 0x02 {
            self.sent.lock().unwrap().push(data.to_vec());
        }
        self.inner.bulk_out(ep, data, timeout)
    }
    fn bulk_in(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, UsbError> {
        self.inner.bulk_in(ep, buf, timeout)
    }
    fn clear_halt(&mut self, ep: u8) -> Result<(), UsbError> {
        self.inner.clear_halt(ep)
    }
    fn iso_bytes_per_interval(&mut self, ep: u8, alt: u8) -> Result<u32, UsbError> {
        self.inner.iso_bytes_per_interval(ep, alt)
    }
    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> Result<StreamHandle, UsbError> {
        self.inner.start_stream(spec, sink)
    }
    fn service(&mut self, timeout: Duration) -> Result<Serviced, UsbError> {
        self.inner.service(timeout)
    }
    fn stop_stream(&mut self, h: StreamHandle, max_wait: Duration) -> Result<(), UsbError> {
        self.inner.stop_stream(h, max_wait)
    }
}

/// The 36-byte 0x3E message of protocol §3.1/§4.10 for `code` and `value`, spelled out byte by
/// byte (little-endian words).
fn color_message(code: u8, value: [u8; 4]) -> Vec<u8> {
    let mut m = vec![
        0x09, 0x20, 0x02, 0x06, // magic 0x06022009
        0x00, 0x00, 0x00, 0x00, // sequence 0 (§3.3)
        0x10, 0x00, 0x00, 0x00, // max_response_len 16
        0x3E, 0x00, 0x00, 0x00, // command id 0x3E
        0x00, 0x00, 0x00, 0x00, // reserved
        0x01, 0x00, 0x00, 0x00, // one setting
        0x00, 0x00, 0x00, 0x00, // setting sequence id 0
        code, 0x00, 0x00, 0x00, // setting code (§4.10 table)
    ];
    m.extend(value);
    m
}

#[test]
fn color_setting_methods_send_the_documented_codes_and_bytes() {
    let sim =
        SimDevice::new(common::synthetic_profile(), SimScene::default(), SimFaults::default());
    let sent = Arc::new(Mutex::new(Vec::new()));
    let mut dev = KinectDevice::open(Spy { inner: sim, sent: sent.clone() }).unwrap();
    dev.start(false, false).unwrap();
    let mark = || sent.lock().unwrap().len();
    let since = |n: usize| sent.lock().unwrap()[n..].to_vec();

    // f32 bit patterns: 1.25 = 0x3FA00000, 1.0 = 0x3F800000, 0.75 = 0x3F400000,
    // 1.5 = 0x3FC00000 (IEEE-754 binary32), little-endian.
    let n = mark();
    dev.set_rgb_gains(1.25, 1.0, 0.75).unwrap();
    assert_eq!(
        since(n),
        vec![
            color_message(11, [0x00, 0x00, 0xA0, 0x3F]),
            color_message(12, [0x00, 0x00, 0x80, 0x3F]),
            color_message(13, [0x00, 0x00, 0x40, 0x3F]),
        ],
        "set red/green/blue gain = codes 11/12/13 with f32 values"
    );
    let n = mark();
    dev.rgb_gains().unwrap();
    assert_eq!(
        since(n),
        vec![color_message(14, [0; 4]), color_message(15, [0; 4]), color_message(16, [0; 4])],
        "get red/green/blue gain = codes 14/15/16"
    );
    let n = mark();
    dev.set_digital_gain(1.5).unwrap();
    assert_eq!(since(n), vec![color_message(19, [0x00, 0x00, 0xC0, 0x3F])], "set digital gain");
    let n = mark();
    dev.digital_gain().unwrap();
    assert_eq!(since(n), vec![color_message(20, [0; 4])], "get digital gain");
    let n = mark();
    dev.set_white_balance_mode(3).unwrap();
    assert_eq!(since(n), vec![color_message(10, [3, 0, 0, 0])], "set white balance (u32)");
    let n = mark();
    dev.white_balance_mode().unwrap();
    assert_eq!(since(n), vec![color_message(81, [0; 4])], "get white balance");
    let n = mark();
    dev.set_color_u32(ColorSettingCode::SetFrameRate, 15).unwrap();
    assert_eq!(since(n), vec![color_message(82, [15, 0, 0, 0])], "set frame rate");
    let n = mark();
    dev.frame_rate_raw().unwrap();
    assert_eq!(since(n), vec![color_message(83, [0; 4])], "get frame rate");
}
