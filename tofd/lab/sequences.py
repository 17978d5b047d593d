"""Rendered sequences with head motion, and the nose track evaluated on them beside the per-frame detection.

Motion (smooth, periodic): the nose distance sweeps 0.35 -> 0.70 -> 0.35 m over `sweep_s`, yaw 30 sin(2 pi t /
4 s) deg, pitch 10 sin(2 pi t / 3 s) deg, the nose tip 12 px left-right about the image centre over 5 s.
A frame's answer is found iff the reported 3-D nose point (the detection's, or the confirmed track's) lies within
radius_m of the true tip, wrong iff a point is reported and it does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.emulator.render import Pose, SensorModel, render_face
from drivers.intrinsics import Intrinsics
from tofd.algorithm.detector import Detection, NoseDetector
from tofd.algorithm.tracking import NoseTracker, TrackerConfig
from tofd.lab.faces import SUBJECTS, make_subject


def head_motion(t_s: np.ndarray, sweep_s: float, intrinsics: Intrinsics) -> list[Pose]:
    """Poses of the module docstring's motion at times t_s (seconds)."""
    phase = (t_s / sweep_s) % 1.0
    distance = 0.35 + 0.35 * (1.0 - np.abs(2.0 * phase - 1.0))
    yaw = 30.0 * np.sin(2 * np.pi * t_s / 4.0)
    pitch = 10.0 * np.sin(2 * np.pi * t_s / 3.0)
    u = intrinsics.cx + 12.0 * np.sin(2 * np.pi * t_s / 5.0)
    return [Pose(float(d), float(y), float(p), nose_px=(float(x), intrinsics.cy))
            for d, y, p, x in zip(distance, yaw, pitch, u, strict=True)]


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


def detect_sequence(detector: NoseDetector, subject: str, frames: int, fps: float = 20.0, sweep_s: float = 6.0,
                    seed: int = 0, model: SensorModel | None = None) -> DetectedSequence:
    """Render `frames` frames of SUBJECT moving (module docstring) at fps and detect the nose in each."""
    if subject not in SUBJECTS:
        raise ValueError(f"unknown subject {subject!r} (known: {', '.join(SUBJECTS)})")
    mesh = make_subject(SUBJECTS[subject])
    rng = np.random.default_rng(seed)
    times = np.arange(frames) / fps
    detections, truth = [], []
    for pose in head_motion(times, sweep_s, detector.intrinsics):
        r = render_face(mesh, pose, detector.intrinsics, rng, model)
        detections.append(detector.detect_frame(r.range_m, r.amplitude))
        truth.append(r.nose_xyz_m)
    return DetectedSequence(subject, times, detections, np.asarray(truth))


def score_sequence(seq: DetectedSequence, radius_m: float = 0.015, tracker: TrackerConfig | None = None
                   ) -> SequenceResult:
    """Found / wrong shares of the per-frame detections and of a track (tracker config) run over them."""
    track = NoseTracker(tracker)
    detected, tracked, reacquired = [], [], 0
    for t, det in zip(seq.times_s, seq.detections, strict=True):
        state = track.update(det, float(t))
        detected.append(det.nose_xyz_m if det.accepted else None)
        tracked.append(state.nose_xyz_m if state.reported else None)
        reacquired += state.reacquired
    d_found, d_wrong = _rates(detected, seq.truth_m, radius_m)
    t_found, t_wrong = _rates(tracked, seq.truth_m, radius_m)
    return SequenceResult(seq.subject, len(seq.times_s), d_found, d_wrong, t_found, t_wrong, reacquired)


def evaluate_sequence(detector: NoseDetector, subject: str, frames: int, fps: float = 20.0, sweep_s: float = 6.0,
                      seed: int = 0, model: SensorModel | None = None, radius_m: float = 0.015,
                      tracker: TrackerConfig | None = None) -> SequenceResult:
    """detect_sequence, then score_sequence."""
    return score_sequence(detect_sequence(detector, subject, frames, fps, sweep_s, seed, model), radius_m, tracker)
