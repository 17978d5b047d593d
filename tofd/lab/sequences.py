"""Rendered sequences with head motion, and the nose track evaluated on them beside the per-frame detection.

Motion (smooth, periodic; `Motion`): the nose distance sweeps 0.35 -> 0.70 -> 0.35 m over `sweep_s`, yaw
yaw_deg sin(2 pi t / 4 s), pitch pitch_deg sin(2 pi t / 3 s), the nose tip's ray drifting drift_deg left-right
about the optical axis over 5 s and drift_v_deg up-down over 7 s (angles, so every camera sees the same motion).
A frame's answer is found iff the reported 3-D nose point (the detection's, or the confirmed track's) lies within
radius_m of the true tip, wrong iff a point is reported and it does not; `score_bins` scores the same answers per
0.05 m distance bin in pixels and in millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.detector import NOSE_RADIUS_M, Detection, NoseDetector
from tofd.algorithm.tracking import NoseTracker, TrackerConfig
from tofd.drivers.emulator.render import Pose, SensorModel, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.faces import SUBJECTS, make_subject


@dataclass(frozen=True, slots=True)
class Motion:
    """Amplitudes of the head motion (module docstring), degrees."""

    yaw_deg: float = 30.0
    pitch_deg: float = 10.0
    drift_deg: float = 3.4  # the nose ray's left-right swing (12 px on the SR3000)
    drift_v_deg: float = 0.0  # its up-down swing


ISSUE_MOTION = Motion(yaw_deg=25.0, pitch_deg=10.0, drift_deg=6.0, drift_v_deg=3.0)
"""Issue 34's evaluation motion: yaw +-25, pitch +-10 deg, drifting across the image."""


def head_motion(t_s: np.ndarray, sweep_s: float, intrinsics: Intrinsics, motion: Motion = Motion()) -> list[Pose]:
    """Poses of the module docstring's motion at times t_s (seconds)."""
    phase = (t_s / sweep_s) % 1.0
    distance = 0.35 + 0.35 * (1.0 - np.abs(2.0 * phase - 1.0))
    yaw = motion.yaw_deg * np.sin(2 * np.pi * t_s / 4.0)
    pitch = motion.pitch_deg * np.sin(2 * np.pi * t_s / 3.0)
    u = intrinsics.cx + intrinsics.fx * np.tan(np.radians(motion.drift_deg * np.sin(2 * np.pi * t_s / 5.0)))
    v = intrinsics.cy + intrinsics.fy * np.tan(np.radians(motion.drift_v_deg * np.sin(2 * np.pi * t_s / 7.0)))
    return [Pose(float(d), float(y), float(p), nose_px=(float(x), float(w)))
            for d, y, p, x, w in zip(distance, yaw, pitch, u, v, strict=True)]


@dataclass(frozen=True, slots=True)
class SequenceResult:
    """Per-frame and tracked answers over one sequence, as shares of its frames."""

    subject: str
    frames: int
    detection_found: float
    detection_wrong: float
    track_found: float
    track_wrong: float
    reacquisitions: int


def _rates(points: list[tuple[float, float, float] | None], truth: np.ndarray, radius_m: float) -> tuple[float, float]:
    hit = [p is not None and float(np.linalg.norm(np.asarray(p) - t)) <= radius_m for p, t in zip(points, truth,
                                                                                                  strict=True)]
    wrong = [p is not None and not h for p, h in zip(points, hit, strict=True)]
    return float(np.mean(hit)), float(np.mean(wrong))


@dataclass(frozen=True, slots=True)
class DetectedSequence:
    """A rendered sequence's per-frame detections and ground truth (the input of the track)."""

    subject: str
    times_s: np.ndarray  # (F,) seconds
    detections: list[Detection]  # (F,)
    truth_m: np.ndarray  # (F, 3) true nose tip, camera frame, metres
    intrinsics: Intrinsics = Intrinsics()  # the camera the sequence was rendered with


def detect_sequence(detector: NoseDetector, subject: str, frames: int, fps: float = 20.0, sweep_s: float = 6.0,
                    seed: int = 0, model: SensorModel | None = None, motion: Motion = Motion()) -> DetectedSequence:
    """Render `frames` frames of SUBJECT moving (module docstring) at fps and detect the nose in each."""
    if subject not in SUBJECTS:
        raise ValueError(f"unknown subject {subject!r} (known: {', '.join(SUBJECTS)})")
    mesh = make_subject(SUBJECTS[subject])
    rng = np.random.default_rng(seed)
    times = np.arange(frames) / fps
    detections, truth = [], []
    for pose in head_motion(times, sweep_s, detector.intrinsics, motion):
        r = render_face(mesh, pose, detector.intrinsics, rng, model)
        detections.append(detector.detect_frame(r.range_m, r.amplitude))
        truth.append(r.nose_xyz_m)
    return DetectedSequence(subject, times, detections, np.asarray(truth), detector.intrinsics)


def score_sequence(seq: DetectedSequence, radius_m: float = NOSE_RADIUS_M, tracker: TrackerConfig | None = None
                   ) -> SequenceResult:
    """Found / wrong shares of the per-frame detections and of a track (tracker config) run over them."""
    track = NoseTracker(tracker)
    detected, tracked, reacquired = [], [], 0
    for t, det in zip(seq.times_s, seq.detections, strict=True):
        state = track.update(det, float(t))
        detected.append(det.answer_xyz_m if det.accepted else None)
        tracked.append(state.nose_xyz_m if state.reported else None)
        reacquired += state.reacquired
    d_found, d_wrong = _rates(detected, seq.truth_m, radius_m)
    t_found, t_wrong = _rates(tracked, seq.truth_m, radius_m)
    return SequenceResult(seq.subject, len(seq.times_s), d_found, d_wrong, t_found, t_wrong, reacquired)


def evaluate_sequence(detector: NoseDetector, subject: str, frames: int, fps: float = 20.0, sweep_s: float = 6.0,
                      seed: int = 0, model: SensorModel | None = None, radius_m: float = NOSE_RADIUS_M,
                      tracker: TrackerConfig | None = None) -> SequenceResult:
    """detect_sequence, then score_sequence."""
    return score_sequence(detect_sequence(detector, subject, frames, fps, sweep_s, seed, model), radius_m, tracker)


NEAR_PX, FAR_PX = 5.0, 10.0  # pixel thresholds: found within, wrong beyond
NEAR_M, FAR_M = 0.010, 0.020  # metric thresholds (3-D distance to the true tip)


@dataclass(frozen=True, slots=True)
class BinScore:
    """The answers of one distance bin (nose range rounded to 0.05 m), as shares of its frames; errors of the
    per-frame detection (`det_`) and of the reported track (`track_`) in pixels and in 3-D millimetres."""

    distance_m: float
    frames: int
    det_within_5px: float
    det_beyond_10px: float
    det_none: float
    det_within_10mm: float
    det_beyond_20mm: float
    track_within_5px: float
    track_beyond_10px: float
    track_none: float
    track_within_10mm: float
    track_beyond_20mm: float
    det_median_mm: float | None  # over frames with an answer
    track_median_mm: float | None


def sequence_answers(seq: DetectedSequence, tracker: TrackerConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) each: the per-frame detection's answer and the reported track's nose, metres (NaN rows: none)."""
    track = NoseTracker(tracker)
    det = np.full((len(seq.times_s), 3), np.nan)
    tracked = det.copy()
    for i, (t, d) in enumerate(zip(seq.times_s, seq.detections, strict=True)):
        state = track.update(d, float(t))
        if d.accepted and d.answer_xyz_m is not None:
            det[i] = d.answer_xyz_m
        if state.reported and state.nose_xyz_m is not None:
            tracked[i] = state.nose_xyz_m
    return det, tracked


def _errors(points: np.ndarray, truth: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: pixel and 3-D (metres) distance of the answers from the truth (NaN: no answer)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        px = np.linalg.norm(intrinsics.project(points) - intrinsics.project(truth), axis=1)
    return px, np.linalg.norm(points - truth, axis=1)


def score_bins(seq: DetectedSequence, tracker: TrackerConfig | None = None) -> list[BinScore]:
    """Per 0.05 m bin of the true nose range: the shares of the module docstring's answers (BinScore)."""
    from tofd.lab.evaluation import distance_bins  # the bins of `tofd evaluate`

    det, tracked = sequence_answers(seq, tracker)
    det_px, det_m = _errors(det, seq.truth_m, seq.intrinsics)
    track_px, track_m = _errors(tracked, seq.truth_m, seq.intrinsics)
    bins = distance_bins(np.linalg.norm(seq.truth_m, axis=1))
    out = []
    for b in np.unique(bins):
        at = bins == b
        share = [float(np.mean(x[at])) for x in (det_px <= NEAR_PX, det_px > FAR_PX, np.isnan(det_px),
                                                  det_m <= NEAR_M, det_m > FAR_M, track_px <= NEAR_PX,
                                                  track_px > FAR_PX, np.isnan(track_px), track_m <= NEAR_M,
                                                  track_m > FAR_M)]
        out.append(BinScore(float(b), int(at.sum()), *share,  # type: ignore[call-arg]  # the ten share fields
                            _median_mm(det_m[at]), _median_mm(track_m[at])))
    return out


def _median_mm(err_m: np.ndarray) -> float | None:
    known = err_m[np.isfinite(err_m)]
    return round(float(np.median(known)) * 1e3, 2) if known.size else None
