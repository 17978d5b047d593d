"""Pinhole camera model of a TOF camera and back-projection of radial range maps."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

SR3000_WIDTH = 176
SR3000_HEIGHT = 144
SR3000_FOV_X_DEG = 47.5


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; pixel (u, v) = (column, row), centre of the top-left pixel is (0, 0)."""

    width: int = SR3000_WIDTH
    height: int = SR3000_HEIGHT
    fx: float = (SR3000_WIDTH / 2) / math.tan(math.radians(SR3000_FOV_X_DEG / 2))
    fy: float = (SR3000_WIDTH / 2) / math.tan(math.radians(SR3000_FOV_X_DEG / 2))
    cx: float = (SR3000_WIDTH - 1) / 2
    cy: float = (SR3000_HEIGHT - 1) / 2

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape (rows, columns)."""
        return self.height, self.width

    def unit_rays(self) -> np.ndarray:
        """(H, W, 3) float64 unit direction of each pixel's ray in the camera frame (x right, y down, z forward).

        Computed once per intrinsics and shared (read-only): segmentation and detection ask for it every frame.
        """
        return _unit_rays(self)

    def pixel_rays(self, u: np.ndarray | float, v: np.ndarray | float) -> np.ndarray:
        """(..., 3) float64 unit rays through (sub)pixel coordinates u (column), v (row) of broadcastable shapes."""
        x = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        y = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        rays = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def backproject(self, range_m: np.ndarray) -> np.ndarray:
        """(H, W, 3) camera-frame points in metres from a radial range map (metres along each pixel's ray)."""
        if range_m.shape != self.shape:
            raise ValueError(f"range_m has shape {range_m.shape}, expected {self.shape}")
        return self.unit_rays() * range_m[..., None]

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates (u, v) of camera-frame points (..., 3) in metres."""
        points = np.asarray(points, dtype=np.float64)
        z = points[..., 2]
        return np.stack([self.fx * points[..., 0] / z + self.cx, self.fy * points[..., 1] / z + self.cy], axis=-1)

    def to_dict(self) -> dict[str, float]:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}

    @classmethod
    def from_dict(cls, d: dict) -> Intrinsics:
        unknown = set(d) - {"width", "height", "fx", "fy", "cx", "cy"}
        if unknown:
            raise ValueError(f"unknown intrinsics key(s): {', '.join(sorted(unknown))}")
        return cls(**d)


@functools.lru_cache(maxsize=8)
def _unit_rays(intrinsics: Intrinsics) -> np.ndarray:
    rays = intrinsics.pixel_rays(np.arange(intrinsics.width)[None, :], np.arange(intrinsics.height)[:, None])
    rays.setflags(write=False)
    return rays
