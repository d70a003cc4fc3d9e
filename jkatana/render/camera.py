"""Pinhole cameras: look-at or orbit placement, primary rays.

World frame as everywhere in jkatana: right-handed, **Y up** (see
:mod:`jkatana.light.envmap`). A camera looks along −z of its own frame
(OpenGL convention); image row 0 is the top of the picture, pixel centres are
sampled (one primary ray per pixel).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jkatana.errors import InputError


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    **Fields:**

    - `position`, `look_at`, `up`: world points/vector (metres).
    - `fov_deg`: vertical field of view in degrees (0 < fov < 180).
    - `width`, `height`: resolution in pixels.
    """

    position: tuple[float, float, float] = (0.0, 0.0, 1.0)
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 40.0
    width: int = 800
    height: int = 600

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise InputError(f"resolution must be at least 1×1 pixels, got {self.width}×{self.height}",
                             field="camera.resolution")
        if not 0.0 < float(self.fov_deg) < 180.0:
            raise InputError(f"fov_deg must lie in (0, 180), got {self.fov_deg}", field="camera.fov_deg")
        f = np.subtract(self.look_at, self.position)
        if not np.all(np.isfinite(f)) or np.linalg.norm(f) < 1e-12:
            raise InputError("camera position and look_at coincide (no viewing direction)",
                             field="camera.look_at")
        if np.linalg.norm(np.cross(f, self.up)) < 1e-9 * np.linalg.norm(f) * max(np.linalg.norm(self.up), 1e-30):
            raise InputError("camera up vector is parallel to the viewing direction", field="camera.up")

    @classmethod
    def orbit(cls, target=(0.0, 0.0, 0.0), distance: float = 1.0, azimuth_deg: float = 0.0,
              elevation_deg: float = 0.0, **kw) -> "Camera":
        """A camera on a sphere about ``target``: azimuth 0 is on +Z, 90° on +X; elevation towards +Y."""
        if not distance > 0:
            raise InputError(f"orbit distance must be > 0, got {distance}", field="camera.distance")
        az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
        d = np.array([math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)])
        pos = tuple(np.add(target, distance * d).tolist())
        return cls(position=pos, look_at=tuple(map(float, target)), **kw)

    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera right, up and forward unit vectors (world)."""
        fwd = np.subtract(self.look_at, self.position).astype(np.float64)
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd)
        return right, up, fwd

    def pose(self) -> np.ndarray:
        """Camera-to-world 4×4 matrix (OpenGL convention: columns right, up, −forward, position), as
        rasterisers (pyrender) take it."""
        right, up, fwd = self.frame()
        pose = np.eye(4)
        pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, -fwd, self.position
        return pose

    def pixel_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(fwd (3,), x·right (width, 3), y·up (height, 3))``: the pinhole's terms per column and row;
        pixel ``(r, c)``'s direction through its centre is ``fwd + x_c·right + y_r·up``, normalised."""
        right, up, fwd = self.frame()
        tan_half = math.tan(math.radians(self.fov_deg) / 2)
        aspect = self.width / self.height
        x = ((np.arange(self.width) + 0.5) / self.width * 2 - 1) * tan_half * aspect
        y = (1 - (np.arange(self.height) + 0.5) / self.height * 2) * tan_half
        return fwd, x[:, None] * right, y[:, None] * up

    def rays(self, index: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(origin (3,), directions (height, width, 3))`` unit world directions through pixel centres;
        with ``index`` (flat pixel indices, row-major) only those pixels' directions ``(n, 3)``, the same
        values as the full frame's."""
        fwd, x_right, y_up = self.pixel_axes()
        if index is None:
            d = fwd + x_right[None, :, :] + y_up[:, None, :]
        else:
            row, col = np.divmod(np.asarray(index, np.int64), self.width)
            d = fwd + x_right[col] + y_up[row]
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.asarray(self.position, np.float64), d

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
