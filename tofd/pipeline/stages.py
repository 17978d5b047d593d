"""The stages of a worker process, kept thin: they adapt the features and detector APIs to shared-memory
slots and to small JSON-ready results."""

from __future__ import annotations

import time

import numpy as np

from drivers.camera import Intrinsics
from tofd.config import Config
from tofd.pipeline.slots import FEATURE_FIELDS

VIEWED_FAMILIES = ("range_fft", "range_nfft")
"""Feature families the pipeline always computes (the viewer shows them, tofd.viewer.blueprint)."""


def pipeline_families(cfg: Config, detect: bool) -> tuple[str, ...]:
    """The feature families a worker computes: the viewed ones plus those of the detector's variant (the NFFT
    amplitude solve costs ~6.6 ms per frame, spent only when the variant uses it)."""
    from tofd.detect import VARIANTS
    from tofd.feature_maps import FAMILIES, families_for

    needed = set(VIEWED_FAMILIES) | (set(families_for(VARIANTS[cfg.detector.variant])) if detect else set())
    return tuple(f for f in FAMILIES if f in needed)


class FeatureStage:
    """Segmentation, the features of pipeline_families, the detector on them; plans made once per worker. The
    maps are tofd.feature_maps.FeatureExtractor's, i.e. what the detector is trained on; maps of families not
    computed are NaN in the slot."""

    def __init__(self, cfg: Config, intrinsics: Intrinsics, detect: bool):
        from tofd.detect import NoseDetector
        from tofd.feature_maps import FeatureExtractor

        self._extractor = FeatureExtractor(intrinsics, cfg.features, cfg.segmentation, pipeline_families(cfg, detect))
        self._detector = NoseDetector(cfg) if detect else None

    def run(self, slot: dict[str, np.ndarray]) -> dict:
        """Read range_m/amplitude from `slot`, write mask and feature maps into it; timings in ms."""
        ff = self._extractor(slot["range_m"], slot["amplitude"])
        slot["mask"][...] = ff.mask
        for name in FEATURE_FIELDS:
            slot[name][...] = ff.maps.get(name, np.nan)
        timings = ff.timings_ms
        reply = {"timings_ms": timings, "nfft_iterations": int(ff.nfft_iterations),
                 "nfft_residual": float(ff.nfft_residual)}
        if self._detector is not None:
            t0 = time.perf_counter()
            det = self._detector.detect_maps(ff.maps, slot["range_m"], ff.rotation[2])
            timings["detection"] = (time.perf_counter() - t0) * 1e3
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

