"""A nose track across frames: an alpha-beta filter on the detected 3-D nose tip, with gating, a confidence,
loss and re-acquisition. Pure: one `update(detection, timestamp_s)` per frame, no I/O.

Per frame the track predicts p + v dt. An accepted detection (its refined tip, else its pixel's point) within the
gate (gate_m + gate_growth_m_per_s x time since the last associated detection, metres in 3-D) corrects it: p +=
alpha r, v += beta r / dt with r the residual. A detection outside the gate is not believed at once (a wrong pixel
of the detector looks like that): it starts a challenger, which replaces the track after `confirm_hits` mutually-
gated detections with none associated to the track in between (the head really moved there). Confidence rises by
`confidence_gain` of its shortfall on each associated detection and decays as exp(-dt / confidence_tau_s) otherwise;
the track is lost after `lost_after_s` without an associated detection. The reported nose is the predicted or
corrected position while the track is confirmed and its last associated detection is at most `report_coast_s` old
(status "tracking"), and with `report_new` that of a new, tentative track in the frames a detection is associated (a
user sees the nose from the first frame; a challenger is never reported before it replaces the track); after that
the track coasts (status "coasting": still predicted and gated, nothing reported) until a detection is associated
again or it is lost, because a prediction without recent support drifts off a moving head.

A frame whose own answer is rejected (none accepted) still feeds a confirmed track when one of its alternatives
(region bests inside the box without the margin test, tofd.algorithm.detector.Alternative) lies inside the gate:
the best-scoring such one is associated (status flag `assisted`), so far-range frames that one frame cannot
settle are answered from the track and the local evidence together.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol, get_args

import numpy as np

Status = Literal["none", "tentative", "coasting", "tracking"]
STATUSES: tuple[Status, ...] = get_args(Status)


class AlternativeLike(Protocol):
    """What the tracker reads of a detection's alternative (tofd.algorithm.detector.Alternative)."""

    @property
    def answer_xyz_m(self) -> tuple[float, float, float]: ...

    @property
    def score(self) -> float: ...


class DetectionLike(Protocol):
    """What the tracker reads of a detection (tofd.algorithm.detector.Detection)."""

    @property
    def answer_xyz_m(self) -> tuple[float, float, float] | None: ...

    @property
    def accepted(self) -> bool: ...

    @property
    def alternatives(self) -> Sequence[AlternativeLike]: ...


@dataclass(frozen=True, slots=True)
class TrackerConfig:
    """Gate, filter gains, confirmation and loss; metres and seconds."""

    gate_m: float = 0.025  # metres: gate radius about the prediction right after an associated detection
    gate_growth_m_per_s: float = 0.25  # metres per second without an associated detection added to the gate
    alpha: float = 0.6  # position gain of the alpha-beta filter
    beta: float = 0.2  # velocity gain
    max_speed_m_per_s: float = 1.5  # velocity estimates are clipped to this speed
    confirm_hits: int = 3  # associated detections before a new track (or a challenger) is reported
    lost_after_s: float = 0.5  # seconds without an associated detection before the track is dropped
    report_coast_s: float = 0.1  # seconds after its last associated detection a confirmed track still reports its
    # nose (chosen on the training subjects' head-motion sequences: bench/tune_tracker.py)
    report_new: bool = True  # a new track (no confirmed one exists) is reported in the frames its detection is
    # associated, before it is confirmed; a challenger never is (the confirmed track is reported meanwhile)
    confidence_gain: float = 0.5  # share of (1 - confidence) gained per associated detection
    confidence_tau_s: float = 0.25  # seconds: e-folding time of the confidence while no detection is associated

    def validate(self) -> None:
        for key in ("gate_m", "max_speed_m_per_s", "lost_after_s", "confidence_tau_s"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key}: {getattr(self, key)} must be > 0")
        for key in ("alpha", "beta", "confidence_gain"):
            if not 0 < getattr(self, key) <= 1:
                raise ValueError(f"{key}: {getattr(self, key)} is not in (0, 1]")
        if self.report_coast_s < 0:
            raise ValueError(f"report_coast_s: {self.report_coast_s} must be >= 0")
        if self.gate_growth_m_per_s < 0:
            raise ValueError(f"gate_growth_m_per_s: {self.gate_growth_m_per_s} must be >= 0")
        if self.confirm_hits < 1:
            raise ValueError(f"confirm_hits: {self.confirm_hits} must be >= 1")


@dataclass(frozen=True, slots=True)
class TrackState:
    """The track after one frame's update."""

    status: Status  # none: no track; tentative: fewer than confirm_hits hits; tracking: confirmed and reported;
    # coasting: confirmed, no associated detection for more than report_coast_s, not reported
    nose_xyz_m: tuple[float, float, float] | None  # filtered position (camera frame, metres); None without a track
    velocity_m_per_s: tuple[float, float, float] | None
    confidence: float  # 0..1
    associated: bool  # this frame's detection was used by the track
    assisted: bool  # ... through one of its alternatives (the frame's own answer was rejected)
    reacquired: bool  # this frame a challenger replaced the track, or a new track was started
    reported: bool = False  # the position is reported as the nose: status "tracking", or (report_new) a new track
    # associated in this frame

    @property
    def confirmed(self) -> bool:
        """A confirmed track, reported or coasting."""
        return self.status in ("tracking", "coasting")


@dataclass(slots=True)
class _Track:
    position: np.ndarray  # (3,) metres
    velocity: np.ndarray  # (3,) metres / second
    last_s: float  # timestamp of the last update
    last_hit_s: float  # timestamp of the last associated detection
    hits: int
    confidence: float


class NoseTracker:
    """Per-frame nose track (module docstring). Timestamps must not decrease; a repeated or earlier timestamp is
    treated as dt = 0."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self.config.validate()
        self._track: _Track | None = None
        self._challenger: _Track | None = None

    def reset(self) -> None:
        self._track = self._challenger = None

    def update(self, detection: DetectionLike | None, timestamp_s: float) -> TrackState:
        """Advance the track to timestamp_s (seconds) with this frame's detection (None or not accepted: none)."""
        xyz = None
        if detection is not None and detection.accepted and detection.answer_xyz_m is not None:
            xyz = np.asarray(detection.answer_xyz_m, dtype=np.float64)
        track = self._track
        reacquired = associated = assisted = False
        if track is not None and xyz is None and detection is not None and track.hits >= self.config.confirm_hits:
            xyz = self._nearby(track, detection.alternatives, timestamp_s)
            assisted = xyz is not None
        if track is not None:
            associated = self._step(track, xyz, timestamp_s)
            if not associated and timestamp_s - track.last_hit_s > self.config.lost_after_s:
                track, self._track, self._challenger = None, None, None
        if xyz is not None and not associated:
            if track is None:
                self._track = track = self._new(xyz, timestamp_s)
                associated = reacquired = True
            else:
                challenger = self._challenger
                if challenger is None or not self._step(challenger, xyz, timestamp_s):
                    self._challenger = challenger = self._new(xyz, timestamp_s)
                if challenger.hits >= self.config.confirm_hits:
                    self._track, self._challenger = challenger, None
                    track, associated, reacquired = challenger, True, True
        elif associated:
            self._challenger = None
        return self._state(track, associated, reacquired, assisted)

    def _nearby(self, track: _Track, alternatives: Sequence[AlternativeLike], t: float) -> np.ndarray | None:
        """The best-scoring alternative inside the confirmed track's gate at t, or None."""
        predicted, gate = self._predict(track, t)
        inside = [(a.score, np.asarray(a.answer_xyz_m, dtype=np.float64)) for a in alternatives]
        inside = [(score, p) for score, p in inside if math.hypot(*(p - predicted)) <= gate]
        return min(inside, key=lambda sp: sp[0])[1] if inside else None

    def _predict(self, track: _Track, t: float) -> tuple[np.ndarray, float]:
        """The track's predicted position at t (metres) and its gate radius then (metres)."""
        cfg = self.config
        predicted = track.position + track.velocity * max(t - track.last_s, 0.0)
        return predicted, cfg.gate_m + cfg.gate_growth_m_per_s * (t - track.last_hit_s)

    def _new(self, xyz: np.ndarray, t: float) -> _Track:
        return _Track(xyz.copy(), np.zeros(3), t, t, 1, self.config.confidence_gain)

    def _step(self, track: _Track, xyz: np.ndarray | None, t: float) -> bool:
        """Predict to t and correct with xyz if it is inside the gate; True iff it was associated."""
        cfg = self.config
        dt = max(t - track.last_s, 0.0)
        predicted, gate = self._predict(track, t)
        track.last_s = t
        residual = None if xyz is None else xyz - predicted
        if residual is not None and math.hypot(*residual) <= gate:  # math: numpy's norm of 3 values costs 10x
            track.position = predicted + cfg.alpha * residual
            if dt > 0:
                velocity = track.velocity + cfg.beta * residual / dt
                speed = math.hypot(*velocity)
                track.velocity = velocity * min(1.0, cfg.max_speed_m_per_s / speed) if speed > 0 else velocity
            track.last_hit_s, track.hits = t, track.hits + 1
            track.confidence += cfg.confidence_gain * (1.0 - track.confidence)
            return True
        track.position = predicted
        track.confidence *= math.exp(-dt / cfg.confidence_tau_s)
        return False

    def _state(self, track: _Track | None, associated: bool, reacquired: bool, assisted: bool) -> TrackState:
        if track is None:
            return TrackState("none", None, None, 0.0, False, False, False)
        status: Status = "tentative"
        if track.hits >= self.config.confirm_hits:
            status = "tracking" if track.last_s - track.last_hit_s <= self.config.report_coast_s else "coasting"
        reported = status == "tracking" or (status == "tentative" and associated and self.config.report_new)
        return TrackState(status, _triple(track.position), _triple(track.velocity), round(track.confidence, 6),
                          associated, assisted and associated, reacquired, reported)


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
