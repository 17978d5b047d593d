"""The public functions' input checks: each raises one ValueError naming the bad argument."""

from __future__ import annotations

import numpy as np

from tofd.algorithm.params import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics

MAX_PLAUSIBLE_RANGE_M = 20.0
"""A median range beyond this (metres) is taken for millimetres: time-of-flight cameras see a few metres."""
MEDIAN_SAMPLES = 4096
"""The millimetre check takes the median of at most about this many of the mask's ranges (evenly spaced)."""


def check_config(config: FeatureConfig | None) -> FeatureConfig:
    """`config`, or the default FeatureConfig for None; ValueError unless it is a FeatureConfig."""
    if config is None:
        return FeatureConfig()
    if not isinstance(config, FeatureConfig):
        raise ValueError(f"config must be a tofd.FeatureConfig, got {type(config).__name__}")
    return config


def check_intrinsics(intrinsics: Intrinsics) -> None:
    """ValueError unless `intrinsics` is a tofd.Intrinsics."""
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics must be a tofd.Intrinsics, got {type(intrinsics).__name__}")


def checked_image(name: str, image: np.ndarray, intrinsics: Intrinsics, allow_integers: bool = False) -> np.ndarray:
    """`image` as an ndarray of the camera's shape and a real number dtype; ValueError naming `name` otherwise."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    kinds = "fiu" if allow_integers else "f"
    if image.dtype.kind not in kinds:
        hint = (" (integer depth in millimetres? use tofd.range_from_depth(depth, intrinsics, scale=0.001))"
                if image.dtype.kind in "iu" else "")
        raise ValueError(f"{name} must be a {'real number' if allow_integers else 'floating-point'} array, "
                         f"got dtype {image.dtype}{hint}")
    if image.shape != intrinsics.shape:
        raise ValueError(f"{name} has shape {image.shape}, expected {intrinsics.shape} (intrinsics height, width)")
    return image


def checked_range(range_m: np.ndarray, intrinsics: Intrinsics, mask: np.ndarray | None) -> np.ndarray:
    """The mask to use (None: every valid pixel) after checking range_m, intrinsics and mask; ValueError naming the
    argument, including for a range that looks like millimetres."""
    check_intrinsics(intrinsics)
    checked_image("range_m", range_m, intrinsics)
    if mask is None:
        with np.errstate(invalid="ignore"):
            mask = np.isfinite(range_m) & (range_m > 0)
    elif not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != intrinsics.shape:
        got = f"{mask.dtype} {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise ValueError(f"mask must be a bool array of shape {intrinsics.shape}, got {got}")
    values = range_m[mask]
    values = values[:: max(1, values.size // MEDIAN_SAMPLES)]
    with np.errstate(invalid="ignore"):
        values = values[np.isfinite(values) & (values > 0)]
    if values.size and (median := float(np.median(values))) > MAX_PLAUSIBLE_RANGE_M:
        raise ValueError(f"range_m looks like millimetres, not metres (median {median:g} over the mask); divide by "
                         "1000, or convert depth with tofd.range_from_depth(depth, intrinsics, scale=0.001)")
    return mask
