"""kfuse from Python: rig files and the exact z-buffered registration of kfuse, NumPy in and out."""

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
        """Every format `kfuse rig import` reads; OSError (unreadable) or ValueError (content)."""
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
    """Exact z-buffered registration (H1 + H2 + H7) and the H8 hole mask, as `kfuse fuse`."""

    def __init__(self, rig: Rig) -> None: ...
    def register(self, depth: _Depth) -> npt.NDArray[np.float32]:
        """uint16 or float32 (depth H, W) mm -> float32 (colour H, W) metres, NaN = no sample."""
    def hole_mask(self) -> npt.NDArray[np.bool_]:
        """bool (colour H, W): disocclusion holes of the last registered frame."""
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
) -> FusedFrame:
    """One frame through `kfuse fuse`'s pipeline with its defaults (linear=False: --resample nearest)."""

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
    """The frames of a .kfrec recording, streamed; Ctrl-C between frames is KeyboardInterrupt."""

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

def to_open3d(
    points: npt.NDArray[np.float32], colors: Optional[npt.NDArray[np.uint8]] = None
) -> Any:
    """Registration.cloud's result as open3d.geometry.PointCloud; ImportError without Open3D."""
