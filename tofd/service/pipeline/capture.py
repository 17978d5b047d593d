"""The capture side: check each frame from the source before it enters the pipeline, and tell device gaps."""

from __future__ import annotations

import math

import numpy as np

from drivers.frame import Frame
from drivers.source import FrameSource

MAX_COUNTER = 2**63 - 1  # frame counters and timestamps must fit an int64 (Rerun's sequence timeline)


def frame_problem(frame: Frame, shape: tuple[int, int]) -> str | None:
    """Why `frame` cannot be processed (wrong plane shape or dtype, non-finite or out-of-range counter and
    timestamp), or None. Pixel values are not checked here: NaN/Inf/zero/negative pixels are the workers'
    business (they give an empty detection)."""
    for name in ("range_m", "amplitude"):
        plane = getattr(frame, name)
        if not isinstance(plane, np.ndarray) or plane.shape != tuple(shape):
            return f"{name} shape {getattr(plane, 'shape', None)} is not {tuple(shape)}"
        if plane.dtype.kind not in "fiu":
            return f"{name} dtype {plane.dtype} is not numeric"
    for name in ("frame_counter", "timestamp_us"):
        value = getattr(frame, name)
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name} {value} is not finite"
        if not 0 <= value <= MAX_COUNTER:
            return f"{name} {value} is outside 0..2^63-1"
    return None


class GapTracker:
    """Device-side gaps between consecutive frames: a reconnect of the source or a frame-counter jump."""

    def __init__(self, source: FrameSource):
        self.source = source
        self._reconnects = source.counters["reconnect"]
        self.last_counter: int | None = None

    def gap_before(self, frame: Frame) -> str:
        """"reconnect", "counter_gap" or "" for `frame`, the next frame of the source."""
        gap = ""
        if self.source.counters["reconnect"] != self._reconnects:
            self._reconnects, gap = self.source.counters["reconnect"], "reconnect"
        elif self.last_counter is not None and frame.frame_counter != self.last_counter + 1:
            gap = "counter_gap"
        self.last_counter = frame.frame_counter
        return gap
