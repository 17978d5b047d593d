"""The capture side: check each frame from the source before it enters the pipeline, and tell device gaps."""

from __future__ import annotations

from tofd.drivers.frame import Frame
from tofd.drivers.source import FrameSource


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
