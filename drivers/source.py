"""The interface every frame source implements: USB camera, emulated camera, recording replay."""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Iterator

from drivers.frame import Frame


class DriverError(RuntimeError):
    """A frame source that cannot be opened or used (no device, access denied, unreadable file)."""


class FrameSource(ABC):
    """A stream of Frames.

    Iterate to receive frames in order; iteration ends at the end of a recording or after close() (which is
    safe to call from another thread). Faults the source survived are counted in `counters` by kind
    (e.g. "timeout", "crc_error", "device_dropped", "reconnect"), so a caller can report them.
    """

    def __init__(self) -> None:
        self.counters: Counter[str] = Counter()
        self._closed = threading.Event()

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
