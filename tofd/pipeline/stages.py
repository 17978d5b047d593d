"""The feature stage of a worker process, kept thin: it adapts the features API to shared-memory slots.

(Detection runs in the parent: tofd.detect.NoseDetector.detect_maps on the maps read back from the slot.)
"""

from __future__ import annotations

import time

import numpy as np

from drivers.camera import Intrinsics
from tofd.config import Config


class FeatureStage:
    """Segmentation -> FFT (range and amplitude) and NFFT (range) features; plans made once per worker.

    Computes the same maps as tofd.feature_maps.FeatureExtractor (what the detector is trained on), timed
    per stage.
    """

    def __init__(self, cfg: Config, intrinsics: Intrinsics):
        from tofd.features import FFTFeatures, NFFTFeatures
        from tofd.segmentation import segment

        self._segment, self._cfg = segment, cfg
        self._fft = FFTFeatures(intrinsics, cfg.features)
        self._nfft = NFFTFeatures(intrinsics, cfg.features)

    def run(self, slot: dict[str, np.ndarray]) -> dict:
        """Read range_m/amplitude from `slot`, write mask and feature maps into it; timings in ms."""
        t0 = time.perf_counter()
        mask = self._segment(slot["range_m"], slot["amplitude"], self._cfg.segmentation)
        slot["mask"][...] = mask
        t1 = time.perf_counter()
        fft_range = self._fft.range_features(slot["range_m"], mask)
        fft_amp = self._fft.amplitude_features(slot["amplitude"], mask)
        t2 = time.perf_counter()
        nfft_range = self._nfft.range_features(slot["range_m"], mask)
        t3 = time.perf_counter()
        for prefix, maps in (("range_fft", fft_range), ("amp_fft", fft_amp), ("range_nfft", nfft_range)):
            slot[f"{prefix}_eps0"][...] = maps.eps0
            slot[f"{prefix}_eps2"][...] = maps.eps2
        return {
            "timings_ms": {"segmentation": (t1 - t0) * 1e3, "fft": (t2 - t1) * 1e3, "nfft": (t3 - t2) * 1e3},
            "nfft_iterations": int(nfft_range.iterations),
            "nfft_residual": float(nfft_range.residual),
            "foreground_px": int(np.count_nonzero(mask)),
        }

