"""The interface every frame source implements (USB camera, emulated camera, recording replay, bags, .mkv files)
and what a source says about itself: its intrinsics, its settings, how many frames to expect and where it stopped."""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

from tofd.drivers.errors import DriverError
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics

__all__ = ["DriverError", "FrameSource", "Rejected", "SourceReport", "StallWatch", "StopReason"]

StopReason = Literal["end", "truncated", "corrupt", "damaged"]
"""Why a file source stopped: read to its end; cut short; unreadable bytes with nothing intact after them; damaged
where the reader cannot tell which of the two."""


@dataclass(frozen=True, slots=True)
class Rejected:
    """Frames the source had (or knows it lost) but does not deliver, counters frame_counter to
    frame_counter + frames - 1 for one reason: the pipeline ledgers them at capture as one range."""

    frame_counter: int
    reason: str  # "invalid_frame: ...", "damaged: ...", "duplicate: ..."
    frames: int = 1


@dataclass(frozen=True, slots=True)
class SourceReport:
    """Where and why a source stopped reading: `reason` None while it has not stopped (or never does: a camera),
    "end" when it read its file to the end, otherwise the damage that stopped it, described by `detail`, after
    the intact frame with counter `last_good_counter` (None: none was read)."""

    reason: StopReason | None = None
    detail: str = ""
    last_good_counter: int | None = None

    @property
    def stopped_early(self) -> bool:
        """Whether damage ended the reading before the end of the file."""
        return self.reason not in (None, "end")

    def line(self) -> str:
        """E.g. "truncated after frame 41: the file ends at byte 30000"."""
        return f"{self.reason} after frame {self.last_good_counter}: {self.detail}"


log = logging.getLogger(__name__)

class FrameSource(ABC):
    """A stream of Frames.

    Iterate to receive frames in order; iteration ends at the end of a recording or after close() (which is
    safe to call from another thread). Faults the source survived are counted in `counters` by kind
    (e.g. "timeout", "crc_error", "device_dropped", "reconnect"), so a caller can report them. Frames the
    source rejects (see `reject`) are queued for the consumer, who takes them with `take_rejected` before
    each frame and at the end, so that every frame is either delivered or accounted for.

    What a source knows about itself: `intrinsics` (the frames' calibration; None until known), `settings` (what
    the device or file says about how it was set, JSON-ready, for provenance), `expected_frames` (how many frames
    a file holds or at most holds, None when unknown or endless) and `report` (where and why it stopped).
    """

    def __init__(self) -> None:
        self.counters: Counter[str] = Counter()
        self.intrinsics: Intrinsics | None = None
        self.settings: dict[str, Any] = {}
        self._closed = threading.Event()
        self._rejected: deque[Rejected] = deque()

    @property
    def expected_frames(self) -> int | None:
        """Frames the source will deliver, or at most delivers (None: unknown or endless)."""
        return None

    @property
    def report(self) -> SourceReport:
        """Where and why reading stopped (SourceReport(): not stopped, or a source that does not end)."""
        return SourceReport()

    def reject(self, frame_counter: int, reason: str, frames: int = 1) -> None:
        """Record `frames` frames from counter `frame_counter` on that will not be delivered (one entry however
        many); counted in counters[reason up to its first ':']."""
        if frames < 1:
            raise ValueError(f"frames: expected >= 1, got {frames}")
        self._rejected.append(Rejected(frame_counter, reason, frames))
        self.counters[reason.split(":")[0]] += frames

    def take_rejected(self) -> list[Rejected]:
        """The rejected frames not taken yet, oldest first (safe against a concurrent `reject`)."""
        out = []
        while self._rejected:
            out.append(self._rejected.popleft())
        return out

    def take_rejected_frames(self) -> int:
        """How many frames the rejected entries not taken yet stand for (takes them)."""
        return sum(r.frames for r in self.take_rejected())

    @abstractmethod
    def __iter__(self) -> Iterator[Frame]: ...

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    def close(self) -> None:
        """Stop the stream; a running iteration ends soon after. Idempotent."""
        self._closed.set()

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StallWatch:
    """The silences of a live source: every wait that ends without a frame is counted (counters["timeout"]), and a
    silence that reaches `stall_report_s` seconds is counted (counters["stall"]) and logged once, until a frame."""

    def __init__(self, counters: Counter[str], stall_report_s: float, name: str) -> None:
        self.counters, self.stall_report_s, self.name = counters, stall_report_s, name
        self.silent_since = time.monotonic()  # host time the current silence started
        self.reported = False  # this silence was reported as a stall

    def streaming_started(self) -> None:
        """Streaming (re)started now: the silence is timed from here."""
        self.silent_since = time.monotonic()

    def frame_arrived(self, now_monotonic_s: float) -> None:
        """A frame arrived at host time `now_monotonic_s`: the silence is over."""
        self.silent_since, self.reported = now_monotonic_s, False

    def timed_out(self) -> bool:
        """Count one wait without a frame; True when it makes the silence a stall (counted and logged now)."""
        self.counters["timeout"] += 1
        silent_s = time.monotonic() - self.silent_since
        if self.reported or silent_s < self.stall_report_s:
            return False
        self.reported = True
        self.counters["stall"] += 1
        log.warning("%s: no frame for %.1f s (%d waits timed out so far); still trying", self.name, silent_s,
                    self.counters["timeout"])
        return True
