//! Helpers shared by the kinect-usb integration tests that need a simulated device but no
//! particular parameters (and no shared data).
#![allow(dead_code)] // each test binary uses a different subset

use kinect_usb::params::DepthParams;
use kinect_usb::sim::SimProfile;

/// A synthetic profile: an ideal depth camera (365 px focal length, principal point at the
/// centre of the 512 × 424 image, no distortion) and a colour camera of 1060 px focal length,
/// with the simulator's real-looking firmware and status answers (`SimProfile::synthetic`).
pub fn synthetic_profile() -> SimProfile {
    let depth = DepthParams {
        fx: 365.0,
        fy: 365.0,
        cx: 255.5,
        cy: 211.5,
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        p1: 0.0,
        p2: 0.0,
    };
    SimProfile::synthetic(depth, 1060.0)
}
