"""The interface every frame source implements: USB camera, emulated camera, recording replay."""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass

from tofd.drivers.frame import Frame


class DriverError(RuntimeError):
    """A frame source that cannot be opened or used (no device, access denied, unreadable file)."""


@dataclass(frozen=True, slots=True)
class Rejected:
    """Frames the source had (or knows it lost) but does not deliver, counters frame_counter to
    frame_counter + frames - 1 for one reason: the pipeline ledgers them at capture as one range."""

    frame_counter: int
    reason: str  # "invalid_frame: ...", "damaged: ...", "duplicate: ..."
    frames: int = 1


class FrameSource(ABC):
    """A stream of Frames.

    Iterate to receive frames in order; iteration ends at the end of a recording or after close() (which is
    safe to call from another thread). Faults the source survived are counted in `counters` by kind
    (e.g. "timeout", "crc_error", "device_dropped", "reconnect"), so a caller can report them. Frames the
    source rejects (see `reject`) are queued for the consumer, who takes them with `take_rejected` before
    each frame and at the end, so that every frame is either delivered or accounted for.
    """

    def __init__(self) -> None:
        self.counters: Counter[str] = Counter()
        self._closed = threading.Event()
        self._rejected: deque[Rejected] = deque()

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
