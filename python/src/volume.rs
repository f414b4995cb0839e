//! `kfuse.Volume`: volumetric fusion (`kfuse-tsdf`, what `kfuse fuse --tsdf` runs) of the
//! frames `kfuse.fuse` returns: each frame's depth (the z of its H1 cloud: units, depth
//! correction and range applied by the fusion request) and its H6 colour on the depth grid,
//! at the depth camera's pose in the volume; one mesh (vertex colours and normals) or the
//! surface points out of it, as arrays or as the CLI's PLY files.

use std::path::PathBuf;
use std::sync::Mutex;

use geometry::{Image, RigidTransform};
use kfuse_tsdf::{DepthFrame, RegisteredColor, TsdfError, TsdfOptions, TsdfVolume};
use nalgebra::{Matrix3, Vector3};
use numpy::PyArray2;
use pyo3::exceptions::{PyMemoryError, PyValueError};
use pyo3::prelude::*;

use crate::fuse::PyFusedFrame;
use crate::{array2, check_output_file, geometry_err, rows};

/// How far a pose's last row may be from `[0, 0, 0, 1]`: the rows of a rigid transform are
/// exact in any file or product of them; 1e-9 leaves room for a printed and re-read value.
const POSE_LAST_ROW_TOLERANCE: f64 = 1e-9;

/// The coordinate frame the PLY files name (the volume's: whatever the poses are relative to).
const VOLUME_FRAME: &str = "the volume's frame (kfuse.Volume: the poses' reference)";

fn tsdf_err(e: TsdfError) -> PyErr {
    match e {
        TsdfError::MemoryBound { .. } => PyMemoryError::new_err(e.to_string()),
        TsdfError::Geometry(g) => geometry_err(g),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// `pose`: a float64 (4, 4) rigid transform, `X_camera = R · X_volume + T` in metres.
fn pose_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<RigidTransform> {
    let Some(obj) = obj else { return Ok(RigidTransform::identity()) };
    let a = array2::<f64>(obj, "pose", "float64", 4, 4)?;
    let m = a.as_array();
    let last = [m[[3, 0]], m[[3, 1]], m[[3, 2]], m[[3, 3]]];
    let expected = [0.0, 0.0, 0.0, 1.0];
    if last.iter().zip(expected).any(|(v, e)| !((v - e).abs() <= POSE_LAST_ROW_TOLERANCE)) {
        return Err(PyValueError::new_err(format!(
            "pose: the last row is {last:?}, not [0, 0, 0, 1]: pass the 4x4 rigid transform camera_from_volume (X_camera = R · X_volume + T, metres)"
        )));
    }
    let r = Matrix3::from_fn(|i, j| m[[i, j]]);
    let t = Vector3::new(m[[0, 3]], m[[1, 3]], m[[2, 3]]);
    RigidTransform::from_matrix(r, t).map_err(|e| PyValueError::new_err(format!("pose: {e}")))
}

/// A truncated signed distance volume (sparse hashed voxel blocks: memory for the surface,
/// not the room) that `kfuse.fuse` frames are integrated into: what `kfuse fuse --tsdf`
/// runs. Volume(voxel_size=0.005, truncation=None, max_memory=None, color=True):
/// voxel_size and truncation in metres (truncation defaults to 0.03 m, or 3 voxels when that
/// is larger), max_memory the bound of the voxel blocks in bytes (default 4 GiB); a value out
/// of range is a ValueError naming it and the range. Depth samples weigh as the Kinect's
/// noise (σ grows with z²); only voxels within the truncation of a sample along its ray are
/// updated, so nothing is carved far behind a surface.
#[pyclass(name = "Volume", module = "kfuse", frozen)]
pub(crate) struct PyVolume {
    /// The volume, behind [`crate::one_call_at_a_time`].
    state: Mutex<TsdfVolume>,
}

impl PyVolume {
    fn volume(&self) -> PyResult<std::sync::MutexGuard<'_, TsdfVolume>> {
        crate::one_call_at_a_time(&self.state, "Volume")
    }
}

#[pymethods]
impl PyVolume {
    /// See the class documentation.
    #[new]
    #[pyo3(signature = (voxel_size = kfuse_tsdf::DEFAULT_VOXEL_SIZE_M, truncation = None, max_memory = None, color = true))]
    fn new(
        voxel_size: f64,
        truncation: Option<f64>,
        max_memory: Option<u64>,
        color: bool,
    ) -> PyResult<Self> {
        let mut options = TsdfOptions::with_voxel_size(voxel_size);
        if let Some(t) = truncation {
            options.truncation_m = t;
        }
        if let Some(m) = max_memory {
            options.max_memory_bytes = m;
        }
        options.color = color;
        let volume = TsdfVolume::new(options).map_err(tsdf_err)?;
        Ok(Self { state: Mutex::new(volume) })
    }

    /// Integrates one frame of `kfuse.fuse` (its depth, after the rig's depth correction and
    /// the depth range, and its colour on the depth grid where the colour camera saw it) with
    /// its depth camera at `pose` (float64 (4, 4), camera_from_volume: X_camera = R · X_volume
    /// + T, metres; None = the identity: the volume is that camera's frame). Returns what the
    /// frame did: {"pixels", "blocks_touched", "blocks_allocated", "voxels_updated"}. Errors
    /// before anything changes: a pose that is not a rigid transform or not finite
    /// (ValueError), more voxel blocks than max_memory (MemoryError).
    #[pyo3(signature = (frame, pose = None))]
    fn integrate<'py>(
        &self,
        py: Python<'py>,
        frame: &PyFusedFrame,
        pose: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let pose = pose_arg(pose)?;
        let mut guard = self.volume()?;
        // The guard stays on this thread; the work gets the volume itself.
        let volume: &mut TsdfVolume = &mut guard;
        let z = frame.depth_z()?;
        let out = frame.output();
        let camera = frame.depth_camera();
        let stats = py
            .detach(|| {
                volume.integrate(&DepthFrame {
                    camera,
                    camera_from_volume: pose,
                    z: &z,
                    color: Some(RegisteredColor {
                        rgb: &out.color_on_depth,
                        valid: &out.color_on_depth_valid,
                    }),
                })
            })
            .map_err(tsdf_err)?;
        let d = pyo3::types::PyDict::new(py);
        d.set_item("pixels", stats.pixels)?;
        d.set_item("blocks_touched", stats.blocks_touched)?;
        d.set_item("blocks_allocated", stats.blocks_allocated)?;
        d.set_item("voxels_updated", stats.voxels_updated)?;
        Ok(d.into_any())
    }

    /// The marching-cubes mesh of the surface, in the volume's frame: vertices (N, 3)
    /// float32 metres, faces (M, 3) uint32 (counter-clockwise seen from the cameras' side),
    /// colours (N, 3) uint8 (grey where no frame gave a colour; (0, 3) with color=False),
    /// unit normals (N, 3) float32 pointing towards the cameras.
    #[allow(clippy::type_complexity)]
    fn mesh<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(
        Bound<'py, PyArray2<f32>>,
        Bound<'py, PyArray2<u32>>,
        Bound<'py, PyArray2<u8>>,
        Bound<'py, PyArray2<f32>>,
    )> {
        let guard = self.volume()?;
        let volume: &TsdfVolume = &guard;
        let mesh = py.detach(|| volume.extract_mesh());
        Ok((
            rows(py, &mesh.vertices)?,
            rows(py, &mesh.faces)?,
            rows(py, &mesh.colors)?,
            rows(py, &mesh.normals)?,
        ))
    }

    /// Writes the mesh as `kfuse fuse --tsdf` does: `tsdf_mesh.ply` (vertex colours and
    /// normals; MeshLab, Blender, CloudCompare and Open3D read it), the same as
    /// `tsdf_mesh.obj` + `.mtl`, and `tsdf_cloud.ply` (the surface points) into `folder`
    /// (created if needed). An existing file is a
    /// FileExistsError naming it unless overwrite=True. Returns the mesh file's path.
    #[pyo3(signature = (folder, overwrite = false))]
    fn save(&self, py: Python<'_>, folder: PathBuf, overwrite: bool) -> PyResult<PathBuf> {
        let mesh_path = folder.join(kfuse_io::fused::TSDF_FILES[0]);
        for name in kfuse_io::fused::TSDF_FILES {
            check_output_file(&folder.join(name), overwrite, "tsdf_mesh.ply", &[])?;
        }
        let guard = self.volume()?;
        let volume: &TsdfVolume = &guard;
        py.detach(|| -> Result<(), geometry::GeometryError> {
            std::fs::create_dir_all(&folder)
                .map_err(|source| geometry::GeometryError::Io { path: folder.clone(), source })?;
            let mesh = volume.extract_mesh();
            kfuse_io::fused::write_tsdf_files(&folder, &mesh.to_mesh(), &mesh.normals, VOLUME_FRAME)
        })
        .map_err(geometry_err)?;
        Ok(mesh_path)
    }

    /// Frames integrated so far.
    #[getter]
    fn frames(&self) -> PyResult<usize> {
        Ok(self.volume()?.frames())
    }

    /// Voxel blocks allocated (8 × 8 × 8 voxels each).
    #[getter]
    fn block_count(&self) -> PyResult<usize> {
        Ok(self.volume()?.block_count())
    }

    /// Bytes the voxel blocks take (what max_memory bounds).
    #[getter]
    fn memory_bytes(&self) -> PyResult<u64> {
        Ok(self.volume()?.memory_bytes())
    }

    /// Edge of a voxel, metres.
    #[getter]
    fn voxel_size(&self) -> PyResult<f64> {
        Ok(self.volume()?.options().voxel_size_m)
    }

    /// Truncation distance, metres.
    #[getter]
    fn truncation(&self) -> PyResult<f64> {
        Ok(self.volume()?.options().truncation_m)
    }

    fn __repr__(&self) -> PyResult<String> {
        let v = self.volume()?;
        Ok(format!(
            "kfuse.Volume(voxel_size={}, truncation={}, frames={}, blocks={})",
            v.options().voxel_size_m,
            v.options().truncation_m,
            v.frames(),
            v.block_count()
        ))
    }
}

/// The z image of a fused frame's depth grid: every H1 point's z at its pixel, NaN elsewhere.
pub(crate) fn z_from_cloud(
    width: usize,
    height: usize,
    cloud: &geometry::PointCloud,
    pixels: &[u32],
) -> PyResult<Image<f32>> {
    let mut z = Image::filled(width, height, f32::NAN);
    let data = z.data_mut();
    for (p, &i) in cloud.points.iter().zip(pixels) {
        let slot = data.get_mut(i as usize).ok_or_else(|| {
            PyValueError::new_err(format!(
                "FusedFrame: a cloud point's pixel {i} is outside the {width}x{height} depth grid"
            ))
        })?;
        *slot = p[2];
    }
    Ok(z)
}
