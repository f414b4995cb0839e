//! The options of a TSDF volume, their Kinect v2 defaults and their validation.

use crate::TsdfError;

/// Default voxel size, metres: 5 mm. A Kinect v2 depth pixel covers ~4 mm at 1.5 m (focal
/// length ~365 px), the distance of a multi-Kinect ring; a smaller voxel than the pixel
/// footprint only adds memory, a larger one smooths away the detail the sensor resolves.
pub const DEFAULT_VOXEL_SIZE_M: f64 = 0.005;
/// Default truncation distance, metres: 30 mm, three times the Kinect's depth noise at 2.5 m
/// (σ(z) = 1.5 mm · z², [`geometry::fusion::KINECT_NOISE_1M_M`]: 9.4 mm) so that a noisy
/// sample still lands in the band around its surface, and six 5 mm voxels (marching cubes
/// and the normals need a few voxels on both sides of the zero crossing).
pub const DEFAULT_TRUNCATION_M: f64 = 0.03;
/// Default memory bound of the voxel blocks, bytes: 2 GiB. A room of 5 × 5 × 3 m seen by
/// several Kinects at 5 mm voxels has ~80 m² of surface, ~100 000 blocks in its band
/// (~1.2 GiB); a bound keeps a wrong voxel size (or a wrong unit) from exhausting the machine.
pub const DEFAULT_MAX_MEMORY_BYTES: u64 = 2 << 30;
/// Smallest voxel size, metres: 1 mm, the Kinect v2's depth resolution (its depth is in whole
/// millimetres); finer voxels resolve nothing more and cost 125× the memory of 5 mm ones.
pub const MIN_VOXEL_SIZE_M: f64 = 0.001;
/// Largest voxel size, metres: 0.5 m. A Kinect sees up to 4.5 m: a coarser grid holds fewer
/// than ten voxels across the whole range, which is no reconstruction (and a voxel size given
/// in millimetres, e.g. 5 or 10, is refused instead of read as metres).
pub const MAX_VOXEL_SIZE_M: f64 = 0.5;
/// Smallest truncation, in voxels: 2. The band must hold a voxel on each side of the surface
/// for marching cubes to find the zero crossing, plus one for the central-difference normals.
pub const MIN_TRUNCATION_VOXELS: f64 = 2.0;
/// Largest truncation, metres: 1 m. The band spreads every sample over twice this depth: more
/// merges separate objects of a room and costs memory for nothing.
pub const MAX_TRUNCATION_M: f64 = 1.0;
/// Kinect v2 minimum operating depth, metres (Microsoft's specification: 0.5–4.5 m).
pub const KINECT_MIN_DEPTH_M: f64 = 0.5;
/// Kinect v2 maximum operating depth, metres (Microsoft's specification: 0.5–4.5 m).
pub const KINECT_MAX_DEPTH_M: f64 = 4.5;
/// Largest depth accepted as an option, metres: 100 m, beyond every depth sensor; a larger
/// value is a unit mistake (millimetres).
pub const MAX_DEPTH_OPTION_M: f64 = 100.0;

/// How a volume is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TsdfOptions {
    /// Edge of a voxel, metres ([`DEFAULT_VOXEL_SIZE_M`]).
    pub voxel_size_m: f64,
    /// Truncation distance μ, metres ([`DEFAULT_TRUNCATION_M`]): voxels within μ of a sample
    /// along its ray, in front of it or behind it, are updated; none farther.
    pub truncation_m: f64,
    /// Memory bound of the voxel blocks, bytes ([`DEFAULT_MAX_MEMORY_BYTES`]).
    pub max_memory_bytes: u64,
    /// Depth samples nearer than this (z, metres) are ignored ([`KINECT_MIN_DEPTH_M`]).
    pub min_depth_m: f64,
    /// Depth samples farther than this (z, metres) are ignored ([`KINECT_MAX_DEPTH_M`]).
    pub max_depth_m: f64,
    /// Keep a colour per voxel (from the registered colour image of each frame).
    pub color: bool,
}

impl Default for TsdfOptions {
    fn default() -> Self {
        Self {
            voxel_size_m: DEFAULT_VOXEL_SIZE_M,
            truncation_m: DEFAULT_TRUNCATION_M,
            max_memory_bytes: DEFAULT_MAX_MEMORY_BYTES,
            min_depth_m: KINECT_MIN_DEPTH_M,
            max_depth_m: KINECT_MAX_DEPTH_M,
            color: true,
        }
    }
}

impl TsdfOptions {
    /// The default options with another voxel size and a truncation of the default or of
    /// [`DEFAULT_TRUNCATION_VOXELS`] voxels, whichever is larger.
    pub fn with_voxel_size(voxel_size_m: f64) -> Self {
        Self {
            voxel_size_m,
            truncation_m: DEFAULT_TRUNCATION_M.max(DEFAULT_TRUNCATION_VOXELS * voxel_size_m),
            ..Self::default()
        }
    }

    /// Checks every option; the error names the option, the value and the accepted range.
    pub fn validate(&self) -> Result<(), TsdfError> {
        let bad = |m: String| Err(TsdfError::InvalidOption(m));
        let v = self.voxel_size_m;
        if !(MIN_VOXEL_SIZE_M..=MAX_VOXEL_SIZE_M).contains(&v) {
            return bad(format!(
                "voxel size {v} m is outside {MIN_VOXEL_SIZE_M}–{MAX_VOXEL_SIZE_M} m (metres, \
                 e.g. 0.005 for 5 mm)"
            ));
        }
        let t = self.truncation_m;
        let t_min = MIN_TRUNCATION_VOXELS * v;
        if !(t_min..=MAX_TRUNCATION_M).contains(&t) {
            return bad(format!(
                "truncation {t} m is outside {t_min}–{MAX_TRUNCATION_M} m (at least \
                 {MIN_TRUNCATION_VOXELS} voxels of {v} m)"
            ));
        }
        if self.max_memory_bytes < BLOCK_BYTES_FOR_OPTIONS {
            return bad(format!(
                "memory bound {} bytes is less than one voxel block ({BLOCK_BYTES_FOR_OPTIONS} \
                 bytes)",
                self.max_memory_bytes
            ));
        }
        let (lo, hi) = (self.min_depth_m, self.max_depth_m);
        if !(lo >= 0.0 && hi > lo && hi <= MAX_DEPTH_OPTION_M) {
            return bad(format!(
                "depth range {lo}–{hi} m must satisfy 0 <= min < max <= {MAX_DEPTH_OPTION_M} m"
            ));
        }
        Ok(())
    }
}

/// Truncation of [`TsdfOptions::with_voxel_size`] in voxels when that exceeds the default
/// truncation: 3, the least that keeps a voxel on each side of the zero crossing plus the
/// neighbours of the normals' central differences.
pub const DEFAULT_TRUNCATION_VOXELS: f64 = 3.0;

/// Bytes of one block as the memory bound counts it (see [`crate::BLOCK_BYTES`]).
const BLOCK_BYTES_FOR_OPTIONS: u64 = crate::BLOCK_BYTES;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        TsdfOptions::default().validate().unwrap();
        TsdfOptions::with_voxel_size(0.01).validate().unwrap();
        TsdfOptions::with_voxel_size(0.2).validate().unwrap();
    }

    #[test]
    fn bad_values_are_refused_with_one_line() {
        for v in [0.0, 1e-9, 10.0, f64::NAN, -0.005, f64::INFINITY] {
            let o = TsdfOptions { voxel_size_m: v, ..TsdfOptions::default() };
            let e = o.validate().unwrap_err().to_string();
            assert!(e.contains("voxel size"), "{e}");
            assert!(!e.contains('\n'), "{e}");
        }
        for t in [0.0, 0.005, 2.0, f64::NAN] {
            let o = TsdfOptions { truncation_m: t, ..TsdfOptions::default() };
            let e = o.validate().unwrap_err().to_string();
            assert!(e.contains("truncation"), "{e}");
        }
        let o = TsdfOptions { max_memory_bytes: 100, ..TsdfOptions::default() };
        assert!(o.validate().unwrap_err().to_string().contains("memory bound"));
        let o = TsdfOptions { min_depth_m: 3.0, max_depth_m: 1.0, ..TsdfOptions::default() };
        assert!(o.validate().unwrap_err().to_string().contains("depth range"));
    }
}
