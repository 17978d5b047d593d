"""One frame's named feature maps: segmentation, then FFT and NFFT eccentricities of range and of amplitude.

Map names are tofd.algorithm.names.MAP_NAMES (each (H, W) float32, NaN outside the foreground). Amplitude
features are those of the amplitude divided by its foreground median, so they do not follow the 1/r^2 fall-off
with distance; the NFFT ones are also scale-invariant (same physical filter at every distance).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from drivers.intrinsics import Intrinsics
from tofd.algorithm.features import Eccentricities, FFTFeatures, NFFTFeatures, SamplingError
from tofd.algorithm.names import FAMILIES, FAMILY_TABLE
from tofd.algorithm.params import FeatureConfig, SegmentationConfig
from tofd.algorithm.segmentation import segment_face


@dataclass(slots=True)
class FrameFeatures:
    """A frame's foreground mask and named eccentricity maps."""

    mask: np.ndarray  # (H, W) bool
    maps: dict[str, np.ndarray]  # name -> (H, W) float32, NaN outside the foreground
    nfft_iterations: int = 0
    nfft_residual: float = float("nan")  # final relative CG residual (NaN: no NFFT family or no foreground)
    timings_ms: dict[str, float] = field(default_factory=dict)  # "segmentation", "fft", "nfft" (if computed)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # camera -> face frame (segmentation)


class FeatureExtractor:
    """Computes the requested feature families for frames of one camera (plans are made once and reused)."""

    def __init__(self, intrinsics: Intrinsics, features: FeatureConfig, segmentation: SegmentationConfig,
                 families: tuple[str, ...] = FAMILIES) -> None:
        unknown = [f for f in families if f not in FAMILIES]
        if unknown:
            raise ValueError(f"unknown feature family {', '.join(unknown)} (known: {', '.join(FAMILIES)})")
        self.intrinsics, self.segmentation, self.families = intrinsics, segmentation, tuple(families)
        self._fft = FFTFeatures(intrinsics, features)
        methods = {FAMILY_TABLE[f].method for f in families}
        self._nfft = NFFTFeatures(intrinsics, features) if "nfft" in methods else None

    def __call__(self, range_m: np.ndarray, amplitude: np.ndarray) -> FrameFeatures:
        t0 = time.perf_counter()
        fg = segment_face(range_m, amplitude, self.segmentation, self.intrinsics)
        mask = fg.mask
        t1 = time.perf_counter()
        timings = {"segmentation": (t1 - t0) * 1e3}
        out = FrameFeatures(mask, {}, timings_ms=timings, rotation=fg.rotation)
        fft_families = [FAMILY_TABLE[f] for f in self.families if FAMILY_TABLE[f].method == "fft"]
        for family in fft_families:
            if family.signal == "range":
                fm = self._fft.range_features(range_m, mask, fg.rotation)
            else:
                fm = self._fft.amplitude_features(amplitude, mask)
            out.maps[family.map_name("eps0")], out.maps[family.map_name("eps2")] = fm.eps0, fm.eps2
        t2 = time.perf_counter()
        if fft_families:
            timings["fft"] = (t2 - t1) * 1e3
        if self._nfft is not None:  # range and amplitude share the points and the Toeplitz kernel
            nfft = {FAMILY_TABLE[f].signal: FAMILY_TABLE[f] for f in self.families if FAMILY_TABLE[f].method == "nfft"}
            rng, amp = self._nfft_features(self._nfft, range_m, mask, fg.rotation,
                                           amplitude if "amp" in nfft else None)
            for signal, nfm in (("range", rng), ("amp", amp)):
                if signal in nfft and nfm is not None:
                    family = nfft[signal]
                    out.maps[family.map_name("eps0")], out.maps[family.map_name("eps2")] = nfm.eps0, nfm.eps2
            out.nfft_iterations, out.nfft_residual = rng.iterations, rng.residual
            timings["nfft"] = (time.perf_counter() - t2) * 1e3
        return out

    def _nfft_features(self, nfft: NFFTFeatures, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray,
                       amplitude: np.ndarray | None) -> tuple[Eccentricities, Eccentricities | None]:
        """The NFFT maps; NaN (no NFFT detection) with a warning where the camera cannot carry the band at the
        foreground's range: wrong numbers would give wrong noses."""
        try:
            return nfft.features(range_m, mask, rotation, amplitude)
        except SamplingError as exc:
            warnings.warn(f"NFFT features left out: {exc}", RuntimeWarning, stacklevel=2)
            empty = Eccentricities.empty(self.intrinsics.shape)
            return empty, (None if amplitude is None else Eccentricities.empty(self.intrinsics.shape))
