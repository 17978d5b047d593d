"""Set-up made once per camera, config and method, reused frame after frame: `FeaturePlan` and its bounded cache.

A plan holds what the feature paths build before their first frame (FFT: the transfer grids, the impulse reach, the
per-box buffers and scipy's plans; NFFT: the finufft plans, the filters on the mode grid, the CG buffers and the
compiled loops). `tofd.eccentricities` and `tofd.surface_filter` take theirs from `cached_plan`, so a notebook
calling them on a stream of frames pays the set-up once; a user who wants to hold it keeps a `FeaturePlan`.
"""

from __future__ import annotations

import functools
import threading
import warnings
from collections import OrderedDict
from typing import get_args

import numpy as np

from tofd.algorithm.features import Eccentricities, FFTFeatures, NFFTFeatures, Transfer
from tofd.algorithm.features.sampling import BandWarning, PatchWarning
from tofd.algorithm.names import Method
from tofd.algorithm.params import FeatureConfig
from tofd.api_inputs import check_config, check_intrinsics, checked_range
from tofd.drivers.intrinsics import Intrinsics

METHODS: tuple[str, ...] = get_args(Method)
PLANS_KEPT = 4
"""Plans `cached_plan` keeps (the most recently used): one per camera, config and method."""
TRANSFERS_KEPT = 4
"""User operators a plan keeps the set-up of (the most recently used), besides the eccentricity filters."""
BAND_WARNING_FRACTION = 0.1
"""NFFT path: a transfer whose magnitude beyond the band edge exceeds this fraction of its peak gets a BandWarning."""
RESULT_DTYPE = np.float64
"""Every public result is float64 (complex128 for operators that are not Hermitian), whatever the path computed in."""


class FeaturePlan:
    """The feature set-up for one camera, config and method, made once; call it frame after frame.

    Parameters
    ----------
    intrinsics : Intrinsics
        The camera; frames must have its shape ``(intrinsics.height, intrinsics.width)``.
    config : FeatureConfig, optional
        Band, grid and solver settings; default ``FeatureConfig()``.
    method : {"nfft", "fft"}
        As in `tofd.eccentricities`.

    Constructing it builds the plans for the eccentricity filters (and, for NFFT, loads the compiled loops);
    user operators get theirs on their first `surface_filter` call. One frame at a time: calls from several
    threads on one plan wait for each other.
    """

    def __init__(self, intrinsics: Intrinsics, config: FeatureConfig | None = None, *, method: Method = "nfft"
                 ) -> None:
        check_intrinsics(intrinsics)
        config = check_config(config)
        check_method(method)
        self.intrinsics, self.config, self.method = intrinsics, config, method
        self._lock = threading.Lock()
        self._eccentricity = self._engine(None)
        self._operators: OrderedDict[object, FFTFeatures | NFFTFeatures] = OrderedDict()

    def __repr__(self) -> str:
        return f"FeaturePlan({self.intrinsics.width}x{self.intrinsics.height}, method={self.method!r})"

    def _engine(self, transfer: Transfer | None) -> FFTFeatures | NFFTFeatures:
        if self.method == "fft":
            return FFTFeatures(self.intrinsics, self.config, transfer)
        engine = NFFTFeatures(self.intrinsics, self.config, transfer)
        if transfer is not None and engine.beyond_band > BAND_WARNING_FRACTION:
            warnings.warn(f"transfer: {engine.beyond_band:.0%} of its peak magnitude lies beyond the band edge "
                          f"{self.config.band_edge_per_m:.1f} cycles/m, where the NFFT fit is damped, not measured: "
                          "its fields there are biased (taper the operator, or widen the band: "
                          "tuning_frequency_per_m, lowpass_sigma_per_m, grid_size)", BandWarning, stacklevel=5)
        return engine

    def _operator_engine(self, transfer: Transfer) -> FFTFeatures | NFFTFeatures:
        """The set-up for a user operator: kept for the TRANSFERS_KEPT most recent hashable ones."""
        try:
            hash(transfer)
        except TypeError:
            return self._engine(transfer)
        if transfer in self._operators:
            self._operators.move_to_end(transfer)
        else:
            self._operators[transfer] = self._engine(transfer)
            if len(self._operators) > TRANSFERS_KEPT:
                self._operators.popitem(last=False)
        return self._operators[transfer]

    def eccentricities(self, range_m: np.ndarray, *, mask: np.ndarray | None = None) -> Eccentricities:
        """`tofd.eccentricities` of one frame with this plan (parameters and result as there)."""
        mask = checked_range(range_m, self.intrinsics, mask)
        out = (np.empty(self.intrinsics.shape, RESULT_DTYPE), np.empty(self.intrinsics.shape, RESULT_DTYPE))
        with self._lock:
            engine = self._eccentricity
            if isinstance(engine, NFFTFeatures):
                result = engine.features(range_m, mask, out=out)[0]
            else:
                result = engine.range_features(range_m, mask, out=out)
            _warn_outside_patch(engine)
        return result

    def surface_filter(self, range_m: np.ndarray, transfer: Transfer, *, mask: np.ndarray | None = None
                       ) -> np.ndarray:
        """`tofd.surface_filter` of one frame with this plan (parameters and result as there)."""
        mask = checked_range(range_m, self.intrinsics, mask)
        if not callable(transfer):
            raise ValueError(f"transfer must be a callable transfer(kx, ky), got {type(transfer).__name__}")
        with self._lock:
            engine = self._operator_engine(transfer)
            fields = engine.filtered(range_m, mask)
            _warn_outside_patch(engine)
        return fields if engine.stacked else fields[0]


def check_method(method: object) -> None:
    """ValueError naming `method` unless it is one of METHODS."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")


def _warn_outside_patch(engine: FFTFeatures | NFFTFeatures) -> None:
    """A PatchWarning when valid pixels of the last frame's mask fell outside the NFFT patch (their result is NaN)."""
    if not isinstance(engine, NFFTFeatures):
        return
    kept, total = engine.last_points
    if (outside := total - kept) > 0:
        cfg = engine.cfg
        warnings.warn(f"range_m: {outside} of {total} points ({outside / total:.0%}) lie outside the "
                      f"{cfg.patch_width_m:.3g} x {cfg.patch_height_m:.3g} m NFFT patch centred on the mask and get "
                      "NaN: pass a mask of one object, or a larger patch (patch_width_m, patch_height_m, with "
                      "grid_size to match)", PatchWarning, stacklevel=4)


@functools.lru_cache(maxsize=PLANS_KEPT)
def cached_plan(intrinsics: Intrinsics, config: FeatureConfig, method: Method) -> FeaturePlan:
    """The FeaturePlan for these arguments, made on first use; the PLANS_KEPT most recently used are kept."""
    return FeaturePlan(intrinsics, config, method=method)
