//! `kfuse.fuse(...)`: one frame through `kfuse fuse`'s pipeline (`fusion_gpu::fuse`: the CPU
//! pipeline `geometry::fusion::run`, or the same stages on the GPU), its outputs as NumPy
//! arrays, and `.save(folder)` through `kfuse_io::fused`, the writer the CLI uses; and
//! `kfuse.Engine`, `--engine`.

use std::path::PathBuf;

use fusion_gpu::{Engine, EngineUsed, GpuError};
use geometry::fusion::{self, FusionOptions, FusionOutput};
use geometry::{DepthKind, Image, Mesh, Rig};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3};
use pyo3::exceptions::{PyFileExistsError, PyRuntimeError, PyRuntimeWarning, PyValueError};
use pyo3::prelude::*;

use crate::{
    METRES_PER_MM, PyRig, color_image, depth_metres, geometry_err, rows, try_copy, try_flat,
};

/// Where the per-pixel stages run, as `kfuse fuse --engine`: Engine("cpu"), Engine("gpu")
/// (wgpu, Vulkan; no adapter is a RuntimeError with the CLI's message) or Engine("auto")
/// (the GPU if there is one, else the CPU with a RuntimeWarning). Results are identical on
/// every engine. Functions that take an engine also take the name.
#[pyclass(name = "Engine", module = "kfuse", frozen, eq)]
#[derive(PartialEq)]
pub(crate) struct PyEngine {
    engine: Engine,
}

#[pymethods]
impl PyEngine {
    /// See the class documentation.
    #[new]
    fn new(name: &str) -> PyResult<Self> {
        Ok(Self { engine: parse_engine(name)? })
    }

    /// "cpu", "gpu" or "auto".
    #[getter]
    fn name(&self) -> &'static str {
        self.engine.name()
    }

    fn __repr__(&self) -> String {
        format!("Engine({:?})", self.engine.name())
    }
}

fn parse_engine(name: &str) -> PyResult<Engine> {
    crate::short_text("engine", name)?
        .parse()
        .map_err(|e: String| PyValueError::new_err(format!("engine: {e}")))
}

/// An `engine` argument: an Engine or its name.
pub(crate) fn engine_arg(obj: &Bound<'_, PyAny>) -> PyResult<Engine> {
    if let Ok(e) = obj.cast::<PyEngine>() {
        return Ok(e.get().engine);
    }
    match obj.extract::<String>() {
        Ok(name) => parse_engine(&name),
        Err(_) => Err(PyValueError::new_err(
            "engine: expected kfuse.Engine or \"cpu\", \"gpu\", \"auto\"",
        )),
    }
}

/// Where the stages ran, in words: "cpu", "gpu: ADAPTER" or "cpu (fallback: REASON)".
pub(crate) fn engine_used_text(used: &EngineUsed) -> String {
    match used {
        EngineUsed::Cpu => "cpu".into(),
        EngineUsed::Gpu { adapter, .. } => format!("gpu: {adapter}"),
        EngineUsed::CpuFallback { reason } => format!("cpu (fallback: {reason})"),
    }
}

/// engine="auto" without an adapter: the CLI's warning as a RuntimeWarning ("REASON; fusing
/// on the CPU", `doing` for "fusing").
pub(crate) fn warn_fallback(py: Python<'_>, used: &EngineUsed, doing: &str) -> PyResult<()> {
    if let EngineUsed::CpuFallback { reason } = used {
        let msg =
            std::ffi::CString::new(format!("{reason}; {doing} on the CPU")).unwrap_or_default();
        PyErr::warn(py, &py.get_type::<PyRuntimeWarning>(), &msg, 1)?;
    }
    Ok(())
}

/// A fusion error: no adapter (or another GPU failure) is a RuntimeError with the CLI's
/// message, bad input a ValueError.
pub(crate) fn gpu_err(e: GpuError) -> PyErr {
    match e {
        GpuError::Input(g) => geometry_err(g),
        other => PyRuntimeError::new_err(other.to_string()),
    }
}

/// A colour-frame depth image as float32 (H, W) metres, NaN = none.
fn depth_array<'py>(py: Python<'py>, img: &Image<f32>) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let (w, h) = img.size();
    let a = Array2::from_shape_vec((h, w), try_copy(img.data(), "FusedFrame")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

/// A mask as bool (H, W).
fn mask_array<'py>(py: Python<'py>, img: &Image<bool>) -> PyResult<Bound<'py, PyArray2<bool>>> {
    let (w, h) = img.size();
    let a = Array2::from_shape_vec((h, w), try_copy(img.data(), "FusedFrame")?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(a.into_pyarray(py))
}

/// `FusedFrame.cloud`'s result: points (N, 3) float32, colours (N, 3) uint8.
type ColoredCloud<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u8>>);

/// `FusedFrame.mesh`'s result: vertices (N, 3) float32, faces (M, 3) uint32, uvs (N, 2)
/// float32.
type MeshArrays<'py> =
    (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u32>>, Bound<'py, PyArray2<f32>>);

fn mesh_arrays<'py>(py: Python<'py>, mesh: &Mesh) -> PyResult<MeshArrays<'py>> {
    Ok((rows(py, &mesh.vertices)?, rows(py, &mesh.faces)?, rows(py, &mesh.uvs)?))
}

/// What `kfuse.fuse` returns: every output of `kfuse fuse` for one frame (less the lab's
/// figures), as arrays; `save(folder)` writes the CLI's files.
///
/// Colour-frame images (zbuffer, nearest, linear, filled, hole_mask) are (colour H, colour W);
/// color_on_depth and its validity are on the depth grid. Depth is float32 metres, NaN = none.
#[pyclass(name = "FusedFrame", module = "kfuse", frozen)]
pub(crate) struct PyFusedFrame {
    out: FusionOutput,
    /// The depth camera as fused (rectification applied): what `kfuse.Volume` integrates with.
    depth_camera: geometry::CameraModel,
    color: Image<[u8; 3]>,
    options: FusionOptions,
    inputs: serde_json::Value,
    used: EngineUsed,
}

impl PyFusedFrame {
    /// Every output of the frame.
    pub(crate) fn output(&self) -> &FusionOutput {
        &self.out
    }

    /// The depth camera as fused.
    pub(crate) fn depth_camera(&self) -> &geometry::CameraModel {
        &self.depth_camera
    }

    /// The fused depth on the depth grid: each H1 point's z at its pixel, NaN elsewhere.
    pub(crate) fn depth_z(&self) -> PyResult<Image<f32>> {
        let c = &self.depth_camera;
        crate::volume::z_from_cloud(c.width, c.height, &self.out.cloud, &self.out.cloud_pixels)
    }
}

#[pymethods]
impl PyFusedFrame {
    /// Where the frame ran: "cpu", "gpu: ADAPTER" or "cpu (fallback: REASON)" (engine="auto"
    /// without an adapter).
    #[getter]
    fn engine_used(&self) -> String {
        engine_used_text(&self.used)
    }

    /// H7 z-buffer: the colour camera's z (depth_zbuffer.exr).
    #[getter]
    fn zbuffer<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        depth_array(py, &self.out.zbuffer)
    }

    /// H3 nearest fill of the z-buffer (depth_nearest.exr).
    #[getter]
    fn nearest<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        depth_array(py, &self.out.nearest)
    }

    /// H3 Delaunay-linear resampling (depth_linear.exr), None with linear=False.
    #[getter]
    fn linear<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        self.out.linear.as_ref().map(|l| depth_array(py, l)).transpose()
    }

    /// H3 nearest with H8's holes filled from the plane (depth_filled.exr).
    #[getter]
    fn filled<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        depth_array(py, &self.out.filled)
    }

    /// H8 disocclusion hole mask (hole_mask.png), bool (colour H, colour W).
    #[getter]
    fn hole_mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<bool>>> {
        mask_array(py, &self.out.hole_mask)
    }

    /// H6 colour on the depth grid (color_on_depth.png): uint8 (depth H, depth W, 3).
    #[getter]
    fn color_on_depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let img = &self.out.color_on_depth;
        let (w, h) = img.size();
        let a = Array3::from_shape_vec((h, w, 3), try_flat(img.data(), "color_on_depth")?)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(a.into_pyarray(py))
    }

    /// H6 validity per depth pixel: bool (depth H, depth W).
    #[getter]
    fn color_on_depth_valid<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<bool>>> {
        mask_array(py, &self.out.color_on_depth_valid)
    }

    /// The cloud of cloud.ply: (points float32 (N, 3) metres, depth camera frame; colors
    /// uint8 (N, 3), black where H6 does not trust the colour).
    #[getter]
    fn cloud<'py>(&self, py: Python<'py>) -> PyResult<ColoredCloud<'py>> {
        Ok((rows(py, &self.out.cloud.points)?, rows(py, &self.out.cloud.colors)?))
    }

    /// H4 mesh (mesh.ply / mesh.obj), colour camera frame: (vertices float32 (N, 3) metres,
    /// faces uint32 (M, 3), counter-clockwise seen from the camera, uvs float32 (N, 2) in the
    /// colour image, OBJ's convention: origin bottom-left).
    #[getter]
    fn mesh<'py>(&self, py: Python<'py>) -> PyResult<MeshArrays<'py>> {
        mesh_arrays(py, &self.out.mesh)
    }

    /// H5: `mesh` without stretched faces (mesh_clean.ply / .obj), same layout.
    #[getter]
    fn mesh_clean<'py>(&self, py: Python<'py>) -> PyResult<MeshArrays<'py>> {
        mesh_arrays(py, &self.out.mesh_clean)
    }

    /// The counts (and per-stage timings, ms) of summary.json's "summary", as a dict.
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let text = serde_json::to_string(&self.out.summary)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        py.import("json")?.call_method1("loads", (text,))
    }

    /// Writes what `kfuse fuse --no-figures --out folder` writes (cloud.ply, depth_*.png/.exr,
    /// hole_mask.png, color_on_depth.png, mesh*.ply/.obj/.mtl/_texture.png, summary.json),
    /// through the CLI's own writer: the folder appears only when complete. An existing
    /// folder is refused (FileExistsError) unless `overwrite`; then it is replaced as fuse
    /// replaces its --out (files of the user's in it stay; one named as an output is refused).
    /// Returns the folder. Releases the GIL.
    #[pyo3(signature = (folder, overwrite = false))]
    fn save(&self, py: Python<'_>, folder: PathBuf, overwrite: bool) -> PyResult<PathBuf> {
        if folder.exists() && !overwrite {
            return Err(PyFileExistsError::new_err(format!(
                "{}: exists; pass overwrite=True to replace its kfuse outputs, or give a new folder",
                folder.display()
            )));
        }
        py.detach(|| {
            kfuse_io::fused::save(&folder, &self.inputs, &self.color, &self.options, &self.out)
        })
        .map_err(geometry_err)
    }

    /// The cloud as an Open3D `open3d.geometry.PointCloud` (points in metres, depth camera
    /// frame; colours in [0, 1]). Open3D is not a dependency of kfuse: without it, ImportError
    /// saying how to install it.
    fn cloud_to_open3d<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let (points, colors) = self.cloud(py)?;
        crate::open3d_cloud(py, points.as_any(), Some(colors.as_any()))
    }

    /// A mesh as an Open3D `open3d.geometry.TriangleMesh` (colour camera frame, vertex colours
    /// in [0, 1], per-corner `triangle_uvs` with OBJ's bottom-left origin): `mesh_clean` (H5)
    /// by default, `mesh` (H4) with clean=False. ImportError without Open3D.
    #[pyo3(signature = (clean = true))]
    fn mesh_to_open3d<'py>(&self, py: Python<'py>, clean: bool) -> PyResult<Bound<'py, PyAny>> {
        let mesh = if clean { &self.out.mesh_clean } else { &self.out.mesh };
        let o3d = crate::open3d(py)?;
        let utility = o3d.getattr("utility")?;
        let m = o3d.getattr("geometry")?.getattr("TriangleMesh")?.call0()?;
        let f64s = |v: &Bound<'py, PyAny>| v.call_method1("astype", ("float64",));
        m.setattr(
            "vertices",
            utility
                .getattr("Vector3dVector")?
                .call1((f64s(rows(py, &mesh.vertices)?.as_any())?,))?,
        )?;
        m.setattr(
            "triangles",
            utility
                .getattr("Vector3iVector")?
                .call1((rows(py, &mesh.faces)?.call_method1("astype", ("int32",))?,))?,
        )?;
        if !mesh.colors.is_empty() {
            let c = rows(py, &mesh.colors)?.call_method1("astype", ("float64",))?;
            let c = c.call_method1("__truediv__", (255.0,))?;
            m.setattr("vertex_colors", utility.getattr("Vector3dVector")?.call1((c,))?)?;
        }
        if !mesh.uvs.is_empty() {
            let corners: Vec<[f32; 2]> =
                mesh.faces.iter().flatten().map(|&i| mesh.uvs[i as usize]).collect();
            let uv = f64s(rows(py, &corners)?.as_any())?;
            m.setattr("triangle_uvs", utility.getattr("Vector2dVector")?.call1((uv,))?)?;
        }
        Ok(m)
    }

    fn __repr__(&self) -> String {
        let s = &self.out.summary;
        format!(
            "FusedFrame({} points, z-buffer {} px, holes {} px, mesh {} -> {} faces)",
            s.points, s.zbuffer_pixels, s.hole_pixels, s.faces_before, s.faces_after
        )
    }
}

/// The fusion options of `kfuse fuse`'s defaults (its `options()`), with `linear` for
/// `--resample both` (True) or `nearest` (False) and `depth_range` for `--depth-range`.
pub(crate) fn cli_options(linear: bool, depth_range: fusion::DepthRange) -> FusionOptions {
    FusionOptions { linear, depth_range, record_timings: true, ..FusionOptions::default() }
}

/// The `depth_range=` keyword: `--depth-range`'s text ("0.5m..2.5m", "500mm..2500mm") or a
/// `(min, max)` pair in metres; None keeps every sample. ValueError naming the keyword.
pub(crate) fn depth_range_arg(arg: Option<&Bound<'_, PyAny>>) -> PyResult<fusion::DepthRange> {
    let Some(arg) = arg.filter(|a| !a.is_none()) else { return Ok(fusion::DepthRange::ALL) };
    let bad = |e: geometry::GeometryError| PyValueError::new_err(format!("depth_range: {e}"));
    if let Ok(text) = arg.extract::<String>() {
        return fusion::DepthRange::parse(crate::short_text("depth_range", &text)?).map_err(bad);
    }
    let (min, max): (f32, f32) = arg.extract().map_err(|_| {
        PyValueError::new_err(
            "depth_range: give \"0.5m..2.5m\" (a unit on the ends) or a (min, max) pair in metres",
        )
    })?;
    fusion::DepthRange::new(min, max).map_err(bad)
}

/// fuse(rig, color, depth, engine="cpu", linear=True, force=False, depth_range=None) -> FusedFrame: one frame through
/// `kfuse fuse`'s pipeline (H1-H8) with its default options, on `engine` (an Engine or
/// "cpu", "gpu", "auto", as --engine).
///
/// `color`: C-contiguous uint8 (colour H, colour W, 3) RGB, as captured (or rectified when
/// the rig says so); `depth`: uint16 (depth H, depth W) z in millimetres, 0 = no sample (the
/// rig's depth correction is applied first, as fuse does). `linear=False` is
/// `--resample nearest`. Depth in another unit (a median depth outside 0.2-15 m, fuse's rule)
/// raises ValueError unless `force` (fuse's `--force`). `depth_range` is `--depth-range`:
/// "0.5m..2.5m" or a (min, max) pair in metres; samples outside are not samples. Releases
/// the GIL.
#[pyfunction]
#[pyo3(signature = (rig, color, depth, engine = None, linear = true, force = false, depth_range = None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn fuse(
    py: Python<'_>,
    rig: &PyRig,
    color: &Bound<'_, PyAny>,
    depth: &Bound<'_, PyAny>,
    engine: Option<&Bound<'_, PyAny>>,
    linear: bool,
    force: bool,
    depth_range: Option<&Bound<'_, PyAny>>,
) -> PyResult<PyFusedFrame> {
    let engine = engine.map(engine_arg).transpose()?.unwrap_or(Engine::Cpu);
    let rectified = rig.rig.rectified;
    let options = cli_options(linear, depth_range_arg(depth_range)?);
    let request = fusion::Request::new(&rig.rig, DepthKind::Z, options).map_err(geometry_err)?;
    let rig: &Rig = request.rig();
    let color = color_image(py, rig, color)?;
    let depth = depth_metres(py, &request, depth, force)?;
    let (out, used) = py
        .detach(|| -> Result<_, GpuError> {
            fusion::checked_coverage_radius_px(rig, &options)?;
            fusion_gpu::fuse_request(engine, &request, &depth, &color)
        })
        .map_err(gpu_err)?;
    warn_fallback(py, &used, "fusing")?;
    // summary.json's "inputs": where the frame came from (the CLI names its files here).
    let mut inputs = serde_json::json!({
        "source": "kfuse Python package (NumPy arrays)",
        "depth_kind": DepthKind::Z,
        "depth_scale_m_per_unit": METRES_PER_MM,
        "rectified": rectified,
    });
    if let Some(c) = &rig.depth_correction {
        inputs["depth_correction"] = serde_json::json!({ "applied": true, "terms": c.describe() });
    }
    Ok(PyFusedFrame { out, depth_camera: rig.depth, color, options, inputs, used })
}
