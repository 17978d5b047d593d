"""The stages of a worker process, kept thin: they adapt the features and detector APIs to shared-memory
slots and to small JSON-ready results."""

from __future__ import annotations

import time

import numpy as np

from tofd.algorithm.detector import Alternative, Detection, NoseDetector, NoseModel
from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.names import FAMILIES, VARIANTS, VIEWED_FAMILIES, families_for, family_maps
from tofd.algorithm.segmentation import foreground_box
from tofd.config import Config
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.service.pipeline.messages import DetectionMessage, FeatureReply
from tofd.service.pipeline.results import FrameResult, box_from, box_list


def pipeline_families(cfg: Config, detect: bool) -> tuple[str, ...]:
    """The feature families a worker computes: the viewed ones plus those of the detector's variant (an
    amplitude family is computed only when the variant uses it)."""
    needed = set(VIEWED_FAMILIES) | (set(families_for(VARIANTS[cfg.detector.variant])) if detect else set())
    return tuple(f for f in FAMILIES if f in needed)


class FeatureStage:
    """Segmentation, the features of pipeline_families, the detector on them; plans made once per worker. The
    maps are tofd.algorithm.extract.FeatureExtractor's, i.e. what the detector is trained on; maps of families not
    computed are left alone in the slot (`maps`: the names of those it computes)."""

    def __init__(self, cfg: Config, intrinsics: Intrinsics, model: NoseModel | None):
        families = pipeline_families(cfg, model is not None)
        self.maps = family_maps(families)
        self._extractor = FeatureExtractor(intrinsics, cfg.features, cfg.segmentation, families)
        self._detector = None if model is None else NoseDetector(model, cfg.detector, cfg.features,
                                                                  cfg.segmentation, intrinsics)

    def run(self, slot: dict[str, np.ndarray]) -> FeatureReply:
        """Read range_m/amplitude from `slot`, write mask and feature maps into it; timings in ms."""
        ff = self._extractor(slot["range_m"], slot["amplitude"], out=slot)  # the maps are written into the slot
        slot["mask"][...] = ff.mask
        timings, box = ff.timings_ms, foreground_box(ff.mask)
        reply = FeatureReply(timings_ms=timings, box=box_list(box), nfft_iterations=int(ff.nfft_iterations),
                             nfft_residual=float(ff.nfft_residual))
        if self._detector is not None:
            t0 = time.perf_counter()
            det = self._detector.detect_maps(ff.maps, slot["range_m"], ff.rotation[2], box)
            timings["detection"] = (time.perf_counter() - t0) * 1e3
            reply["detection"] = detection_dict(det)
        return reply


def detection_dict(det: Detection) -> DetectionMessage:
    """A Detection as a JSON-ready dict (score may be inf: no foreground); each alternative as one list
    [u, v, x, y, z, score] (+ [tip x, y, z] when refined)."""
    return DetectionMessage(nose_px=None if det.nose_px is None else list(det.nose_px),
                            nose_xyz_m=None if det.nose_xyz_m is None else list(det.nose_xyz_m), score=det.score,
                            accepted=det.accepted, tip_px=None if det.tip_px is None else list(det.tip_px),
                            tip_xyz_m=None if det.tip_xyz_m is None else list(det.tip_xyz_m),
                            alternatives=[[*a.px, *a.xyz_m, a.score, *(a.tip_xyz_m or ())]
                                          for a in det.alternatives])


def frame_result(seq: int, frame: Frame, views: dict[str, np.ndarray], reply: FeatureReply, maps: tuple[str, ...], *,
                 arrival_s: float = 0.0, gap_before: str = "",
                 timings_ms: dict[str, float] | None = None) -> FrameResult:
    """The FrameResult of `frame` from a FeatureStage reply and the slot it filled (the computed `maps`, copied out
    of the slot); `timings_ms` are stages timed outside the worker, put before the worker's."""
    return FrameResult(
        seq=seq, frame=frame, mask=views["mask"].copy(), features={name: views[name].copy() for name in maps},
        nfft_iterations=reply["nfft_iterations"], nfft_residual=reply["nfft_residual"], arrival_s=arrival_s,
        box=box_from(reply["box"]),
        gap_before=gap_before, detection=detection_from(reply.get("detection")),
        timings_ms={**(timings_ms or {}), **reply["timings_ms"]})


def process_frame(stage: FeatureStage, frame: Frame, slot: dict[str, np.ndarray], seq: int = 0) -> FrameResult:
    """One frame through `stage` in one process (slot: tofd.service.pipeline.slots.local_slot of the frame's
    shape): the pipeline workers' computation without shared memory, for batch re-processing."""
    slot["range_m"][...] = frame.range_m
    slot["amplitude"][...] = frame.amplitude
    return frame_result(seq, frame, slot, stage.run(slot), stage.maps)


def detection_from(d: DetectionMessage | None) -> Detection | None:
    """The Detection of detection_dict, or None (no detector)."""
    if d is None:
        return None
    px, xyz, tip_px, tip_xyz = d["nose_px"], d["nose_xyz_m"], d["tip_px"], d["tip_xyz_m"]
    alternatives = tuple(Alternative((int(a[0]), int(a[1])), (a[2], a[3], a[4]), a[5],
                                     (a[6], a[7], a[8]) if len(a) > 6 else None) for a in d["alternatives"])
    return Detection((int(px[0]), int(px[1])) if px else None,
                     (float(xyz[0]), float(xyz[1]), float(xyz[2])) if xyz else None, float(d["score"]),
                     bool(d["accepted"]), (float(tip_px[0]), float(tip_px[1])) if tip_px else None,
                     (float(tip_xyz[0]), float(tip_xyz[1]), float(tip_xyz[2])) if tip_xyz else None, alternatives)

