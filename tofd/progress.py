"""A one-line progress report on stderr for long runs: done/total, frames per second, ETA."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Rewrites one stderr line at most every `interval_s` seconds; done() ends the line."""

    def __init__(self, label: str, total: int, stream: TextIO | None = None, interval_s: float = 0.5) -> None:
        # sys.stderr looked up per instance, not bound at import (it may be replaced, e.g. by a test's capture)
        self.label, self.total, self.stream, self.interval_s = label, total, stream or sys.stderr, interval_s
        self.start = time.monotonic()
        self._last = -float("inf")
        self.count = 0

    def update(self, count: int, total: int | None = None) -> None:
        self.count = count
        self.total = total if total is not None else self.total
        now = time.monotonic()
        if now - self._last >= self.interval_s or count >= self.total:
            self._last = now
            rate = count / max(now - self.start, 1e-9)
            eta = (self.total - count) / rate if rate > 0 else float("inf")
            self.stream.write(f"\r{self.label}: {count}/{self.total} frames, {rate:.1f} frames/s, ETA {eta:.0f} s  ")
            self.stream.flush()

    def done(self) -> float:
        """End the line; returns the elapsed seconds."""
        elapsed = time.monotonic() - self.start
        self.stream.write(f"\r{self.label}: {self.count}/{self.total} frames in {elapsed:.1f} s" + " " * 20 + "\n")
        self.stream.flush()
        return elapsed
