"""tofd: scale-invariant range features and nose detection for time-of-flight cameras (Haker et al. 2008).

The public API works on your own arrays (docs/API.md)::

    import tofd
    camera = tofd.Intrinsics(width=320, height=240, fx=228.5, fy=228.5, cx=159.5, cy=119.5)
    features = tofd.eccentricities(range_m, camera)          # .eps0, .eps2: (H, W), NaN outside the surface
    fields = tofd.surface_filter(range_m, camera, transfer)  # any operator given by its transfer(kx, ky)
    plan = tofd.FeaturePlan(camera)                          # the set-up kept, for a stream of frames

Names load on first use, so ``import tofd`` stays light (the daemon, viewer, USB and recordings load only when
their commands run).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_EXPORTS = {
    "Intrinsics": "tofd.drivers.intrinsics",
    "FeatureConfig": "tofd.algorithm.params",
    "Eccentricities": "tofd.algorithm.features",
    "SamplingError": "tofd.algorithm.features",
    "PatchWarning": "tofd.algorithm.features",
    "BandWarning": "tofd.algorithm.features",
    "FeaturePlan": "tofd.plan",
    "radial_tuning": "tofd.algorithm.band",
    "band_edge_per_m": "tofd.algorithm.band",
    "BAND_FLOOR": "tofd.algorithm.band",
    "eccentricities": "tofd.api",
    "surface_filter": "tofd.api",
    "eccentricity_transfer": "tofd.api",
    "range_from_depth": "tofd.api",
    "Detection": "tofd.algorithm.detector",
    "NOSE_RADIUS_M": "tofd.algorithm.detector",
    "ModelMismatch": "tofd.algorithm.detector",
    "NoseModel": "tofd.algorithm.detector",
    "load_model": "tofd.algorithm.detector",
    "save_model": "tofd.algorithm.detector",
    "detect_nose": "tofd.api_detect",
    "render_dataset": "tofd.api_detect",
    "load_dataset": "tofd.api_detect",
    "train_model": "tofd.api_detect",
    "evaluate_model": "tofd.api_detect",
}
"""Public name -> the module that defines it."""

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'tofd' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # the same names for type checkers (tests/api/test_api.py checks both lists agree)
    from tofd.algorithm.band import BAND_FLOOR as BAND_FLOOR
    from tofd.algorithm.band import band_edge_per_m as band_edge_per_m
    from tofd.algorithm.band import radial_tuning as radial_tuning
    from tofd.algorithm.detector import NOSE_RADIUS_M as NOSE_RADIUS_M
    from tofd.algorithm.detector import Detection as Detection
    from tofd.algorithm.detector import ModelMismatch as ModelMismatch
    from tofd.algorithm.detector import NoseModel as NoseModel
    from tofd.algorithm.detector import load_model as load_model
    from tofd.algorithm.detector import save_model as save_model
    from tofd.algorithm.features import BandWarning as BandWarning
    from tofd.algorithm.features import Eccentricities as Eccentricities
    from tofd.algorithm.features import PatchWarning as PatchWarning
    from tofd.algorithm.features import SamplingError as SamplingError
    from tofd.algorithm.params import FeatureConfig as FeatureConfig
    from tofd.api import eccentricities as eccentricities
    from tofd.api import eccentricity_transfer as eccentricity_transfer
    from tofd.api import range_from_depth as range_from_depth
    from tofd.api import surface_filter as surface_filter
    from tofd.api_detect import detect_nose as detect_nose
    from tofd.api_detect import evaluate_model as evaluate_model
    from tofd.api_detect import load_dataset as load_dataset
    from tofd.api_detect import render_dataset as render_dataset
    from tofd.api_detect import train_model as train_model
    from tofd.drivers.intrinsics import Intrinsics as Intrinsics
    from tofd.plan import FeaturePlan as FeaturePlan
