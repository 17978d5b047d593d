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

from tofd.algorithm.features import Eccentricities, FFTFeatures, NFFTFeatures, SamplingError
from tofd.algorithm.features.eccentricity import MapsOut
from tofd.algorithm.names import FAMILIES, FAMILY_TABLE, Family
from tofd.algorithm.params import FeatureConfig, SegmentationConfig
from tofd.algorithm.segmentation import segment_face
from tofd.drivers.intrinsics import Intrinsics


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

    def __call__(self, range_m: np.ndarray, amplitude: np.ndarray,
                 out: dict[str, np.ndarray] | None = None) -> FrameFeatures:
        """The frame's features; `out`: (H, W) float32 arrays by map name (e.g. a worker's shared-memory slot) that
        the maps of the computed families are written into and returned as, instead of new arrays."""
        t0 = time.perf_counter()
        fg = segment_face(range_m, amplitude, self.segmentation, self.intrinsics)
        mask = fg.mask
        t1 = time.perf_counter()
        timings = {"segmentation": (t1 - t0) * 1e3}
        result = FrameFeatures(mask, {}, timings_ms=timings, rotation=fg.rotation)
        fft_families = [FAMILY_TABLE[f] for f in self.families if FAMILY_TABLE[f].method == "fft"]
        for family in fft_families:
            if family.signal == "range":
                fm = self._fft.range_features(range_m, mask, fg.rotation, out=maps_out(out, family))
            else:
                fm = self._fft.amplitude_features(amplitude, mask, out=maps_out(out, family))
            result.maps[family.map_name("eps0")], result.maps[family.map_name("eps2")] = fm.eps0, fm.eps2
        t2 = time.perf_counter()
        if fft_families:
            timings["fft"] = (t2 - t1) * 1e3
        if self._nfft is not None:  # range and amplitude share the points and the Toeplitz kernel
            rng, amp = self._nfft_features(self._nfft, range_m, mask, fg.rotation, amplitude, out)
            for family in (FAMILY_TABLE["range_nfft"], FAMILY_TABLE["amp_nfft"]):
                nfm = rng if family.signal == "range" else amp
                if family.name in self.families and nfm is not None:
                    result.maps[family.map_name("eps0")], result.maps[family.map_name("eps2")] = nfm.eps0, nfm.eps2
            result.nfft_iterations, result.nfft_residual = rng.iterations, rng.residual
            timings["nfft"] = (time.perf_counter() - t2) * 1e3
        return result

    def _nfft_features(self, nfft: NFFTFeatures, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray,
                       amplitude: np.ndarray,
                       out: dict[str, np.ndarray] | None) -> tuple[Eccentricities, Eccentricities | None]:
        """The NFFT maps; NaN (no NFFT detection) with a warning where the camera cannot carry the band at the
        foreground's range: wrong numbers would give wrong noses."""
        amplitude_or_none = amplitude if "amp_nfft" in self.families else None
        range_out = maps_out(out, FAMILY_TABLE["range_nfft"]) if "range_nfft" in self.families else None
        amplitude_out = maps_out(out, FAMILY_TABLE["amp_nfft"]) if amplitude_or_none is not None else None
        try:
            return nfft.features(range_m, mask, rotation, amplitude_or_none, range_out, amplitude_out)
        except SamplingError as exc:
            warnings.warn(f"NFFT features left out: {exc}", RuntimeWarning, stacklevel=2)
            empty = Eccentricities.empty(self.intrinsics.shape, out=range_out)
            return empty, (None if amplitude_or_none is None else Eccentricities.empty(self.intrinsics.shape,
                                                                                        out=amplitude_out))


def maps_out(out: dict[str, np.ndarray] | None, family: Family) -> MapsOut | None:
    """The arrays of `out` for a family's eps0 and eps2 maps (None: new arrays)."""
    return None if out is None else (out[family.map_name("eps0")], out[family.map_name("eps2")])
