"""Rolling per-stage timings, end-to-end latency and frame rate of the pipeline (thread-safe)."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from tofd.algorithm.detector import Detection
from tofd.algorithm.tracking import TrackState

TIMED_STAGES = ("capture", "queue", "segmentation", "fft", "nfft", "detection", "logging", "latency")
"""Per-frame timings in milliseconds; "queue" is the wait for a worker, "latency" is capture -> sink done."""


class PipelineStats:
    """The last `window` timings of every stage and the completion times of the last `window` frames."""

    def __init__(self, window: int = 600) -> None:
        self._lock = threading.Lock()
        self._timings: dict[str, deque[float]] = {stage: deque(maxlen=window) for stage in TIMED_STAGES}
        self._done: deque[float] = deque(maxlen=window)  # monotonic seconds of delivered frames
        self.started_s = time.monotonic()

    def record(self, timings_ms: dict[str, float]) -> None:
        """Add one delivered frame's timings (keys from TIMED_STAGES; missing stages are skipped)."""
        now = time.monotonic()
        with self._lock:
            for stage, ms in timings_ms.items():
                if stage in self._timings:
                    self._timings[stage].append(ms)
            self._done.append(now)

    def quantiles_ms(self, q: tuple[float, ...] = (0.5, 0.99)) -> dict[str, tuple[float, ...]]:
        """Per-stage quantiles in milliseconds over the window (stages with no samples are left out)."""
        with self._lock:
            samples = {s: np.fromiter(d, float) for s, d in self._timings.items() if d}
        return {s: tuple(float(v) for v in np.quantile(x, q)) for s, x in samples.items()}

    def fps(self, horizon_s: float = 5.0) -> float:
        """Delivered frames per second over the last `horizon_s` seconds (or since start)."""
        now = time.monotonic()
        with self._lock:
            recent = [t for t in self._done if t >= now - horizon_s]
        span = min(horizon_s, now - self.started_s)
        return len(recent) / span if span > 0 else 0.0

    def last_delivery_age_s(self) -> float | None:
        """Seconds since the last delivered frame (None before the first)."""
        with self._lock:
            last = self._done[-1] if self._done else None
        return None if last is None else time.monotonic() - last


@dataclass(frozen=True, slots=True)
class TrackSnapshot:
    """The nose track as TrackStats reports it: the latest status ("none" before the first frame) and confidence
    (0-1), the frame and track counts of TrackStats and the last refined tip."""

    status: str
    confidence: float
    detected_frames: int
    tracked_frames: int
    acquired: int
    lost: int
    tip_frames: int  # frames whose accepted detection has a refined sub-pixel tip
    tip_xyz_m: tuple[float, float, float] | None  # the last refined tip (camera frame, metres; None before one)


class TrackStats:
    """The nose track as /metrics and the run summary report it: its latest state, frames with an accepted
    detection, with a sub-pixel tip refined from it, and with a reported track nose, the last refined tip (camera
    frame, metres), and how often a confirmed track began (acquired: a new track confirmed, or a challenger
    replacing the track) or was lost (dropped without a confirmed successor, a new tentative track started in the
    same frame included); coasting does not end a track."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._last: TrackState | None = None
        self._detected = self._tips = self._tracked = self._acquired = self._lost = 0
        self._tip: tuple[float, float, float] | None = None

    def record(self, detection: Detection | None, state: TrackState) -> None:
        """Count one frame's detection and the track after it (frames in pipeline order)."""
        with self._lock:
            before = self._last is not None and self._last.confirmed
            self._detected += detection is not None and detection.accepted
            if detection is not None and detection.accepted and detection.tip_xyz_m is not None:
                self._tips += 1
                self._tip = detection.tip_xyz_m
            self._tracked += state.reported
            self._acquired += state.confirmed and (not before or state.reacquired)
            self._lost += before and not state.confirmed  # hits never fall: only a loss unconfirms
            self._last = state

    def snapshot(self) -> TrackSnapshot:
        with self._lock:
            last = self._last
            return TrackSnapshot("none" if last is None else last.status, 0.0 if last is None else last.confidence,
                                 self._detected, self._tracked, self._acquired, self._lost, self._tips, self._tip)
