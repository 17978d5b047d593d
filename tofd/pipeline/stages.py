"""The stages of a worker process, kept thin: they adapt the features and detector APIs to shared-memory
slots and to small JSON-ready results."""

from __future__ import annotations

import time

import numpy as np

from drivers.camera import Intrinsics
from tofd.config import Config
from tofd.pipeline.slots import FEATURE_FIELDS


class FeatureStage:
    """Segmentation -> FFT (range and amplitude) and NFFT (range) features; plans made once per worker.

    Computes the same maps as tofd.feature_maps.FeatureExtractor (what the detector is trained on), timed
    per stage.
    """

    def __init__(self, cfg: Config, intrinsics: Intrinsics, detect: bool):
        from tofd.detect import NoseDetector
        from tofd.features import FFTFeatures, NFFTFeatures
        from tofd.segmentation import segment_face

        self._segment, self._cfg, self._intrinsics = segment_face, cfg, intrinsics
        self._fft = FFTFeatures(intrinsics, cfg.features)
        self._nfft = NFFTFeatures(intrinsics, cfg.features)
        self._detector = NoseDetector(cfg) if detect else None

    def run(self, slot: dict[str, np.ndarray]) -> dict:
        """Read range_m/amplitude from `slot`, write mask and feature maps into it; timings in ms."""
        t0 = time.perf_counter()
        fg = self._segment(slot["range_m"], slot["amplitude"], self._cfg.segmentation, self._intrinsics)
        mask = fg.mask
        slot["mask"][...] = mask
        t1 = time.perf_counter()
        fft_range = self._fft.range_features(slot["range_m"], mask, fg.rotation)
        fft_amp = self._fft.amplitude_features(slot["amplitude"], mask)
        t2 = time.perf_counter()
        nfft_range = self._nfft.range_features(slot["range_m"], mask, fg.rotation)
        t3 = time.perf_counter()
        for prefix, maps in (("range_fft", fft_range), ("amp_fft", fft_amp), ("range_nfft", nfft_range)):
            slot[f"{prefix}_eps0"][...] = maps.eps0
            slot[f"{prefix}_eps2"][...] = maps.eps2
        timings = {"segmentation": (t1 - t0) * 1e3, "fft": (t2 - t1) * 1e3, "nfft": (t3 - t2) * 1e3}
        reply = {"timings_ms": timings, "nfft_iterations": int(nfft_range.iterations),
                 "nfft_residual": float(nfft_range.residual)}
        if self._detector is not None:
            maps = {name: slot[name] for name in FEATURE_FIELDS}
            det = self._detector.detect_maps(maps, slot["range_m"])
            timings["detection"] = (time.perf_counter() - t3) * 1e3
            reply["detection"] = {"nose_px": det.nose_px, "nose_xyz_m": det.nose_xyz_m, "score": det.score,
                                  "accepted": det.accepted}
        return reply


def detection_from(message: dict):
    """The tofd.detect.Detection in a worker's reply, or None (no detector)."""
    from tofd.detect import Detection

    d = message.get("detection")
    if d is None:
        return None
    return Detection(tuple(d["nose_px"]) if d["nose_px"] else None,
                     tuple(d["nose_xyz_m"]) if d["nose_xyz_m"] else None, float(d["score"]), bool(d["accepted"]))

