"""kfuse from Python: rig files and the exact z-buffered registration of kfuse, NumPy in and out.

No call aborts the interpreter: bad input raises ValueError / TypeError / OSError (or a
subclass), arrays that do not fit in memory MemoryError, text arguments that take a name
(engine, board, backend, ...) longer than 256 characters ValueError
(tests/test_worst_sizes.py)."""

import os
import pathlib
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]
# Depth in millimetres: uint16 (a 16-bit PNG) or float32 (Decoder's and Recording's output).
_Depth = Union[npt.NDArray[np.uint16], npt.NDArray[np.float32]]

class Camera:
    """One camera of a rig."""

    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def K(self) -> npt.NDArray[np.float64]:
        """3x3 camera matrix, OpenCV's layout [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]."""
    @property
    def dist(self) -> npt.NDArray[np.float64]:
        """Distortion (k1, k2, p1, p2, k3), OpenCV's order."""

class Rig:
    """A depth + colour camera pair: X_color = R @ X_depth + T (metres)."""

    @staticmethod
    def load(path: _Path, *more: _Path, force: bool = False) -> "Rig":
        """Every format `kfuse rig import` reads; OSError (unreadable) or ValueError (content).
        A rig of mirrored images (a version-1 kinect_params.json, a Kinect rig with its colour
        camera on the mirrored side) loads with a UserWarning saying how to convert it."""
    @staticmethod
    def from_kinect_params(path: _Path, force: bool = False) -> "Rig":
        """A sensor's kinect_params.json (`kfuse capture`) as `kfuse rig import` reads it;
        ValueError for any other format (use Rig.load), OSError when unreadable."""
    def save(self, path: _Path, overwrite: bool = False) -> None:
        """kfuse rig JSON, atomically; FileExistsError unless overwrite."""
    @property
    def depth(self) -> Camera: ...
    @property
    def color(self) -> Camera: ...
    @property
    def R(self) -> npt.NDArray[np.float64]: ...
    @property
    def T(self) -> npt.NDArray[np.float64]: ...
    @property
    def rectified(self) -> bool: ...

class Registration:
    """Exact z-buffered registration (H1 + H2 + H7) and the H8 hole mask, as `kfuse fuse`,
    on the CPU or the GPU (bit-identical results)."""

    def __init__(
        self,
        rig: Rig,
        engine: Union["Engine", str, None] = None,
        force: bool = False,
        depth_range: Union[str, Tuple[float, float], None] = None,
    ) -> None:
        """engine: "cpu" (default), "gpu" (RuntimeError without an adapter) or "auto" (GPU if
        any, else CPU with a RuntimeWarning), as kfuse.fuse. Every frame's depth unit is
        checked as `kfuse fuse` checks it: a median depth outside 0.2-15 m raises ValueError
        (metres, 0.1 mm, a 65535 fill); force=True lets it through. depth_range: --depth-range
        ("0.5m..2.5m") or (min, max) metres; samples outside are none."""
    @property
    def engine(self) -> str:
        """"cpu" or "gpu": where the stages run (what engine="auto" picked)."""
    @property
    def engine_used(self) -> str:
        """"cpu", "gpu: ADAPTER" or "cpu (fallback: REASON)"."""
    def register(
        self, depth: _Depth, out: Optional[npt.NDArray[np.float32]] = None
    ) -> npt.NDArray[np.float32]:
        """uint16 or float32 (depth H, W) mm -> float32 (colour H, W) metres, NaN = no sample;
        registered straight into `out` (writable, C-contiguous, that shape; any content) when
        given, which is returned: no copy on the CPU, no allocation per frame."""
    def hole_mask(self, out: Optional[npt.NDArray[np.bool_]] = None) -> npt.NDArray[np.bool_]:
        """bool (colour H, W): disocclusion holes of the last registered frame; into `out`
        when given."""
    def color_on_depth(
        self, color: npt.NDArray[np.uint8]
    ) -> Tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
        """uint8 (colour H, W, 3) -> (uint8 (depth H, W, 3), valid bool (depth H, W))."""
    def cloud(
        self, depth: _Depth, color: Optional[npt.NDArray[np.uint8]] = None
    ) -> Tuple[npt.NDArray[np.float32], Optional[npt.NDArray[np.uint8]]]:
        """fuse's cloud.ply: (points float32 (N, 3) m, depth frame; colors uint8 (N, 3) or None).
        With color the frame is registered (it becomes the last frame)."""

_Mesh = Tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32], npt.NDArray[np.float32]]

class Engine:
    """Where fuse's per-pixel stages run, as --engine: "cpu", "gpu" (RuntimeError without an
    adapter, the CLI's message) or "auto" (GPU if any, else CPU with a RuntimeWarning)."""

    def __init__(self, name: str) -> None: ...
    @property
    def name(self) -> str: ...

class FusedFrame:
    """Every output of `kfuse fuse` for one frame (less the lab's figures) as arrays."""

    @property
    def engine_used(self) -> str:
        """"cpu", "gpu: ADAPTER" or "cpu (fallback: REASON)"."""
    @property
    def zbuffer(self) -> npt.NDArray[np.float32]:
        """H7 z-buffer, float32 (colour H, W) metres, NaN = none (depth_zbuffer.exr)."""
    @property
    def nearest(self) -> npt.NDArray[np.float32]: ...
    @property
    def linear(self) -> Optional[npt.NDArray[np.float32]]: ...
    @property
    def filled(self) -> npt.NDArray[np.float32]: ...
    @property
    def hole_mask(self) -> npt.NDArray[np.bool_]: ...
    @property
    def color_on_depth(self) -> npt.NDArray[np.uint8]: ...
    @property
    def color_on_depth_valid(self) -> npt.NDArray[np.bool_]: ...
    @property
    def cloud(self) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
        """cloud.ply: points (N, 3) m in the depth frame, colours (N, 3)."""
    @property
    def mesh(self) -> _Mesh:
        """H4 (vertices (N, 3) m colour frame, faces uint32 (M, 3), uvs (N, 2))."""
    @property
    def mesh_clean(self) -> _Mesh:
        """H5: mesh without stretched faces."""
    @property
    def summary(self) -> Dict[str, Any]:
        """summary.json's "summary": counts and per-stage timings (ms)."""
    def cloud_to_open3d(self) -> Any:
        """open3d.geometry.PointCloud of `cloud`; ImportError without Open3D."""
    def mesh_to_open3d(self, clean: bool = True) -> Any:
        """open3d.geometry.TriangleMesh of mesh_clean (or mesh); ImportError without Open3D."""
    def save(self, folder: _Path, overwrite: bool = False) -> pathlib.Path:
        """What `kfuse fuse --no-figures --out folder` writes; FileExistsError unless overwrite."""

def fuse(
    rig: Rig,
    color: npt.NDArray[np.uint8],
    depth: _Depth,
    engine: Union[Engine, str, None] = None,
    linear: bool = True,
    force: bool = False,
    depth_range: Union[str, Tuple[float, float], None] = None,
) -> FusedFrame:
    """One frame through `kfuse fuse`'s pipeline with its defaults (linear=False: --resample nearest).
    Depth whose median is outside 0.2-15 m (another unit) raises ValueError unless force.
    depth_range: --depth-range ("0.5m..2.5m") or (min, max) metres; samples outside are none."""

class Volume:
    """A sparse TSDF (what `kfuse fuse --tsdf` runs) that kfuse.fuse frames integrate into.
    voxel_size / truncation in metres (truncation: 0.03, or 3 voxels if larger), max_memory in
    bytes; out-of-range values are ValueErrors."""

    def __init__(
        self,
        voxel_size: float = 0.005,
        truncation: Optional[float] = None,
        max_memory: Optional[int] = None,
        color: bool = True,
    ) -> None: ...
    def integrate(
        self, frame: FusedFrame, pose: Optional[npt.NDArray[np.float64]] = None
    ) -> Dict[str, int]:
        """The frame's depth and colour at pose (4x4 camera_from_volume, metres; None =
        identity). MemoryError past max_memory, ValueError for a bad pose; nothing changes."""
    def mesh(
        self,
    ) -> Tuple[
        npt.NDArray[np.float32],
        npt.NDArray[np.uint32],
        npt.NDArray[np.uint8],
        npt.NDArray[np.float32],
    ]:
        """Marching cubes: vertices (N, 3) m, faces (M, 3), colours (N, 3), normals (N, 3)."""
    def save(self, folder: _Path, overwrite: bool = False) -> pathlib.Path:
        """tsdf_mesh.ply (colours, normals) and tsdf_cloud.ply into folder."""
    @property
    def frames(self) -> int: ...
    @property
    def block_count(self) -> int: ...
    @property
    def memory_bytes(self) -> int: ...
    @property
    def voxel_size(self) -> float: ...
    @property
    def truncation(self) -> float: ...

def read_depth(path: _Path) -> npt.NDArray[np.float32]:
    """A depth file read as `kfuse fuse --depth` reads it: float32 metres, NaN = no sample."""

class Decoder:
    """Kinect v2 depth decoder on the CPU: raw 2 984 960-byte frames -> (depth mm, IR)."""

    def __init__(
        self,
        p0_tables: bytes,
        x_table: npt.NDArray[np.float32],
        z_table: npt.NDArray[np.float32],
        bilateral: bool = True,
        edge_aware: bool = True,
        orientation: str = "scene",
        precision: str = "fast",
    ) -> None: ...
    def decode(self, raw: bytes) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """(depth mm, IR), float32 (424, 512) each; depth 0 = no measurement."""

def decode(
    raw: bytes,
    p0_tables: bytes,
    x_table: npt.NDArray[np.float32],
    z_table: npt.NDArray[np.float32],
    bilateral: bool = True,
    edge_aware: bool = True,
    orientation: str = "scene",
    precision: str = "fast",
) -> Tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Decoder(p0_tables, x_table, z_table, ...).decode(raw) in one call: (depth mm, IR)."""

class RecordingFrame:
    """A depth frame of a recording and its colour partner, as `kfuse fuse --recording` pairs them."""

    @property
    def number(self) -> int: ...
    @property
    def depth_sequence(self) -> int: ...
    @property
    def depth_time_ticks(self) -> int:
        """Sensor time, ticks of 0.125 ms."""
    @property
    def depth_time(self) -> float:
        """Sensor time, seconds."""
    @property
    def depth(self) -> npt.NDArray[np.float32]:
        """float32 (424, 512) millimetres, 0 = none, as the scene is."""
    @property
    def raw_depth(self) -> bytes: ...
    @property
    def color_jpeg(self) -> Optional[bytes]:
        """The sensor's JPEG (mirrored left-right), None without a partner."""
    @property
    def color_time_ticks(self) -> Optional[int]: ...
    @property
    def color_time(self) -> Optional[float]: ...
    def color(self) -> Optional[npt.NDArray[np.uint8]]:
        """The partner decoded as the scene is, uint8 (1080, 1920, 3)."""

class Recording:
    """The frames of a .kfrec recording, streamed; Ctrl-C between frames is KeyboardInterrupt.

    Usable from any thread (e.g. a ThreadPoolExecutor worker), one call at a time: a call
    while another thread's call on the same Recording runs is a RuntimeError. Dropped in any
    thread, it closes the file."""

    def __init__(
        self, path: _Path, allow_truncated: bool = False, skip_corrupt: bool = False
    ) -> None: ...
    def __iter__(self) -> "Recording": ...
    def __next__(self) -> RecordingFrame: ...
    @property
    def lost(self) -> List[Dict[str, Any]]:
        """index.json's "missing": number, depth_sequence, reason."""
    @property
    def info(self) -> Dict[str, str]: ...
    @property
    def path(self) -> pathlib.Path: ...

class DeviceFrame:
    """A depth + colour pair of a live sensor, both received after next_frame() began."""

    @property
    def number(self) -> int:
        """Depth frames decoded since the device opened."""
    @property
    def depth(self) -> npt.NDArray[np.float32]:
        """float32 (424, 512) millimetres, 0 = none, as the scene is."""
    @property
    def ir(self) -> npt.NDArray[np.float32]:
        """float32 (424, 512) IR amplitude, as the scene is."""
    @property
    def color_jpeg(self) -> bytes:
        """The sensor's JPEG (mirrored left-right)."""
    @property
    def depth_timestamp(self) -> Optional[int]:
        """Sensor ticks of 0.125 ms."""
    @property
    def color_timestamp(self) -> Optional[int]: ...
    def color(self) -> npt.NDArray[np.uint8]:
        """Decoded as the scene is, uint8 (1080, 1920, 3); releases the GIL."""

def devices(backend: str = "usb", sim_sensors: int = 1) -> List[Dict[str, Optional[str]]]:
    """`kfuse devices`: serial and line of every sensor; OSError without one."""

class Device:
    """A Kinect v2 opened and streaming ("usb", or "sim": the simulated sensor); no sensor is
    an OSError with the CLI's message. A context manager; iterating yields DeviceFrames.

    Usable from any thread (e.g. a ThreadPoolExecutor worker), one call at a time: a call
    while another thread's call on the same Device runs (a record() say) is a RuntimeError.
    Dropped in any thread, it releases the sensor."""

    def __init__(
        self, backend: str = "usb", serial: Optional[str] = None, sim_sensors: int = 1
    ) -> None:
        """sim_sensors 2..4: one sensor of the simulated ring (the first, or `serial`)."""
    @property
    def info(self) -> Dict[str, str]:
        """serial, firmware."""
    def next_frame(self, timeout: float = 3.0) -> DeviceFrame:
        """A fresh depth + colour pair; waits at most timeout s (0 < timeout <= 60)."""
    def __iter__(self) -> "Device": ...
    def __next__(self) -> DeviceFrame: ...
    def record(self, path: _Path, frames: int, overwrite: bool = False) -> Dict[str, Any]:
        """A .kfrec of `frames` depth frames (1..=108000), written atomically: frames, path,
        stopped_by. An existing path is a FileExistsError (nothing recorded, the file left as
        it was) unless overwrite; a folder a ValueError. Ctrl-C writes the frames so far, then
        raises KeyboardInterrupt."""
    def write_params(self, folder: _Path, overwrite: bool = False) -> pathlib.Path:
        """folder/kinect_params.json, the factory parameters (Rig.from_kinect_params);
        FileExistsError when that file exists, unless overwrite."""
    def close(self) -> None:
        """Releases the sensor (again: nothing)."""
    def __enter__(self) -> "Device": ...
    def __exit__(self, *args: Any) -> bool: ...

def to_open3d(
    points: npt.NDArray[np.float32], colors: Optional[npt.NDArray[np.uint8]] = None
) -> Any:
    """Registration.cloud's result as open3d.geometry.PointCloud; ImportError without Open3D."""

# One camera's images: a glob pattern or file (expanded and sorted as --ir / --color), or a
# list of image files or of uint8 (H, W) grey arrays, kept in list order.
_Images = Union[_Path, List[_Path], List[npt.NDArray[np.uint8]]]

class CameraFit:
    """One calibrated camera: final K / dist (the joint fit's for stereo), their 1σ, and its
    single-camera fit's per-image table."""

    @property
    def name(self) -> str:
        """"IR" or "colour"."""
    @property
    def camera(self) -> Camera: ...
    @property
    def K(self) -> npt.NDArray[np.float64]:
        """3x3, OpenCV's layout [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] (px)."""
    @property
    def dist(self) -> npt.NDArray[np.float64]:
        """(k1, k2, p1, p2, k3), OpenCV's order."""
    @property
    def K_std(self) -> npt.NDArray[np.float64]:
        """1σ of K entry by entry: [[σfx, σskew, σcx], [0, σfy, σcy], [0, 0, 0]]."""
    @property
    def dist_std(self) -> npt.NDArray[np.float64]:
        """1σ of dist (k1, k2, p1, p2, k3)."""
    @property
    def rms_px(self) -> float:
        """This camera's RMS reprojection error, px (after the joint fit for stereo)."""
    @property
    def sigma_px(self) -> float: ...
    @property
    def views(self) -> List[Dict[str, Any]]:
        """Per image: name, corners, rms_px, tilt_deg, rejected (None or why)."""
    @property
    def rejected_corners(self) -> List[Dict[str, Any]]:
        """Outlier corners: view, id, error_px, threshold_px."""

class Calibration:
    """What `kfuse calibrate` computes (calib::pipeline), as Python values."""

    @property
    def rig(self) -> Optional[Rig]:
        """The rig of a stereo run; None for one camera."""
    @property
    def ir(self) -> Optional[CameraFit]: ...
    @property
    def color(self) -> Optional[CameraFit]: ...
    @property
    def rms_px(self) -> float:
        """The joint fit's RMS over both cameras (stereo), or the camera's, px."""
    @property
    def pairs(self) -> Optional[List[Dict[str, Any]]]:
        """Stereo, per pair: ir, color, ir_rms_px, color_rms_px, ir_weight, color_weight,
        used, rejected."""
    @property
    def rejected_views(self) -> List[Tuple[str, str, str]]:
        """(camera "IR" / "colour" / "pair", image name, reason) of every view left out."""
    @property
    def board(self) -> Tuple[int, int, float, Optional[bool]]:
        """(cols, rows, square_m, top_left_black): the size found with board="auto"."""
    @property
    def report(self) -> Dict[str, Any]:
        """report.json's content less timings_ms (held_out with held_out=True)."""
    @property
    def text(self) -> str:
        """The file `kfuse calibrate --out` writes, byte for byte."""
    @property
    def warnings(self) -> List[str]:
        """The run's warnings (also issued as UserWarning)."""
    def save(self, path: _Path, overwrite: bool = False) -> None:
        """`text` written atomically; FileExistsError unless overwrite. One of the image files
        calibrated from (through any path to it) is a ValueError even with overwrite."""

def calibrate(
    ir: Optional[_Images] = None,
    color: Optional[_Images] = None,
    board: str = "auto",
    square: Union[float, str, None] = None,
    held_out: bool = False,
    top_left: Optional[str] = None,
) -> Calibration:
    """`kfuse calibrate`'s run: board "COLSxROWS" inner corners or "auto"; square in metres
    or with a unit ("40mm"; None = 40 mm); ValueError / OSError with the library's message."""
