//! What the simulated device answers to commands ([`SimProfile`]): firmware, hardware info,
//! serial, factory parameters and status words, from the test vectors or synthetic.

use crate::params::{ColorParams, DepthParams, P0Tables};
use crate::protocol;
use crate::raw::PIXELS;

/// What the simulated device answers to commands.
#[derive(Debug, Clone)]
pub struct SimProfile {
    /// Firmware records (record 3 is shown to users).
    pub firmware: [(u16, u16, u32, u32); 7],
    /// 92 bytes of hardware info.
    pub hardware_info: Vec<u8>,
    /// Serial number.
    pub serial: String,
    /// Depth intrinsics.
    pub depth_params: DepthParams,
    /// P0 tables.
    pub p0: P0Tables,
    /// Colour parameters.
    pub color_params: ColorParams,
    /// Status words returned by successive polls (the last one repeats).
    pub status_words: Vec<u32>,
    /// `wBytesPerInterval` of endpoint 0x84.
    pub bytes_per_interval: u32,
}

/// Largest vector file a profile reads: 64 MiB. The responses are at most 1.3 MB (the P0
/// tables); the limit bounds what a wrong file, a device or a pipe can make it read.
const MAX_PROFILE_FILE_BYTES: u64 = 64 << 20;

impl SimProfile {
    /// A profile from the vectors' inputs (real factory intrinsics, synthetic P0 and colour
    /// parameters) with a real-looking firmware version and status sequence.
    pub fn from_vectors(dir: &std::path::Path) -> crate::Result<Self> {
        let read_bytes = |path: &std::path::Path| {
            let expected = bounded_read::Expected {
                what: "a simulator vector file",
                fix: "is the vectors folder the right one?",
            };
            bounded_read::read_bounded(path, MAX_PROFILE_FILE_BYTES, expected)
                .map_err(|source| crate::KinectError::File { path: path.to_path_buf(), source })
        };
        let hw = read_bytes(&dir.join("real/protocol/hardware_info_response.bin"))?;
        Ok(SimProfile {
            firmware: [
                (1, 0, 0, 0),
                (2, 0, 0, 0),
                (3, 0, 0, 0),
                (4, 0, 3912, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
            ],
            hardware_info: hw,
            serial: "016293740947".into(),
            depth_params: DepthParams::from_response(&read_bytes(
                &dir.join("inputs/depth_camera_params_response.bin"),
            )?)?,
            p0: P0Tables::from_response(&read_bytes(&dir.join("inputs/p0_tables_response.bin"))?)?,
            color_params: ColorParams::from_response(&read_bytes(
                &dir.join("inputs/rgb_camera_params_response.bin"),
            )?)?,
            status_words: vec![1024, 9729, 9731],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        })
    }

    /// A self-contained profile for given depth intrinsics: smooth synthetic P0 tables and
    /// pinhole-like colour parameters (colour focal length `color_f`, principal point at the
    /// image centre, the real devices' `shift_d = 863`, `shift_m = 52`).
    pub fn synthetic(depth: DepthParams, color_f: f32) -> Self {
        let base = [11_418.0f64, 2_284.0, 17_128.0];
        let tables = std::array::from_fn(|k| {
            (0..PIXELS)
                .map(|i| {
                    let (x, y) = ((i % 512) as f64 / 511.0 - 0.5, (i / 512) as f64 / 423.0 - 0.5);
                    (base[k] + 900.0 * x - 600.0 * y + 1200.0 * (x * x + y * y)).round() as u16
                })
                .collect()
        });
        // Polynomial coefficients of a pinhole mapping (protocol §11.1 inverted for x, y linear).
        const QD: f32 = 0.01;
        const QC: f32 = 0.002199;
        let (shift_d, shift_m) = (863.0f32, 52.0f32);
        let mut mx = [0f32; 10];
        let mut my = [0f32; 10];
        mx[7] = color_f * QC / (QD * depth.fx);
        mx[9] = shift_m / shift_d * color_f * QC;
        my[8] = color_f * QC / (QD * depth.fy);
        SimProfile {
            firmware: [
                (1, 0, 0, 0),
                (2, 0, 0, 0),
                (3, 0, 0, 0),
                (4, 0, 3912, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
                (0, 0, 0, 0),
            ],
            hardware_info: vec![0u8; 92],
            serial: "000000000001".into(),
            depth_params: depth,
            p0: P0Tables { tables },
            color_params: ColorParams {
                f: color_f,
                cx: 959.5,
                cy: 539.5,
                shift_d,
                shift_m,
                mx,
                my,
            },
            status_words: vec![1024, 9729, 9731],
            bytes_per_interval: protocol::MIN_BYTES_PER_INTERVAL,
        }
    }

    pub(super) fn firmware_bytes(&self) -> Vec<u8> {
        let mut v = vec![0u8; 0x200];
        for (i, &(maj, min, rev, build)) in self.firmware.iter().enumerate() {
            let r = &mut v[16 * i..16 * i + 16];
            r[0..4].copy_from_slice(&(((maj as u32) << 16) | min as u32).to_le_bytes());
            r[4..8].copy_from_slice(&rev.to_le_bytes());
            r[8..12].copy_from_slice(&build.to_le_bytes());
        }
        v
    }
}
