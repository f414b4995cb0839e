"""kfuse from Python: rig files and the exact z-buffered registration of kfuse, NumPy in and out."""

import os
from typing import Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]

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
    def register(self, depth: npt.NDArray[np.uint16]) -> npt.NDArray[np.float32]:
        """uint16 (depth H, W) mm -> float32 (colour H, W) metres, NaN = no sample."""
    def hole_mask(self) -> npt.NDArray[np.bool_]:
        """bool (colour H, W): disocclusion holes of the last registered frame."""
    def color_on_depth(
        self, color: npt.NDArray[np.uint8]
    ) -> Tuple[npt.NDArray[np.uint8], npt.NDArray[np.bool_]]:
        """uint8 (colour H, W, 3) -> (uint8 (depth H, W, 3), valid bool (depth H, W))."""

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
