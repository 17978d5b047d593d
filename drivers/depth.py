"""Depth cameras' z-depth images as tofd's radial range: the one conversion every depth-camera source uses."""

from __future__ import annotations

import numpy as np

from tofd.drivers.intrinsics import Intrinsics


def depth_metres(raw: np.ndarray, metres_per_unit: float) -> np.ndarray:
    """(H, W) float32 metres of integer depth values (0 = no return -> NaN) or of float metres as they are."""
    if raw.dtype.kind == "f":
        return raw.astype(np.float32, copy=False)
    metres = (raw.astype(np.float64) * metres_per_unit).astype(np.float32)
    metres[raw == 0] = np.nan
    return metres


def range_from_depth(depth: np.ndarray, metres_per_unit: float, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W) float32 radial range in metres along each pixel's ray (through the lens) of a z-depth image."""
    return intrinsics.radial_from_z(depth_metres(depth, metres_per_unit)).astype(np.float32)
