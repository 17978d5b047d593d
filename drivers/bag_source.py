"""What every bag-backed frame source shares: the open bag, the range conversions, the calibration check, the
account of a damaged tail, and what the file says about the device and its settings."""

from __future__ import annotations

import logging
from abc import abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from drivers.bag_scan import BagError, BagReader, DamagedMessage, RawMessage
from drivers.frame import Frame
from drivers.intrinsics import Intrinsics
from drivers.source import FrameSource, Rejected

log = logging.getLogger(__name__)


def depth_metres(raw: np.ndarray, metres_per_unit: float) -> np.ndarray:
    """(H, W) float32 metres of integer depth values (0 = no return -> NaN) or of float metres as they are."""
    if raw.dtype.kind == "f":
        return raw.astype(np.float32, copy=False)
    metres = (raw.astype(np.float64) * metres_per_unit).astype(np.float32)
    metres[raw == 0] = np.nan
    return metres


class BagSource(FrameSource):
    """A FrameSource reading a bag through drivers.bag_scan.BagReader.

    After iteration, `intrinsics` is the calibration of the frames (None when none was delivered), `damage` says
    why reading stopped early (None: the whole bag was read) and `settings` holds what the file says about the
    device and how it was set (units, rates, options), for the provenance of an imported recording.
    """

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        self.path = Path(path)
        self.bag = BagReader(self.path)
        self.intrinsics: Intrinsics | None = None
        self.settings: dict[str, Any] = {}
        self.range_messages: int | None = None
        """Range images in the bag (an upper bound on the frames; None when unknown)."""

    def message_count(self, topic: str) -> int | None:
        """Messages of `topic` in the bag, None when unknown (a damaged sqlite3 bag read row by row)."""
        n = self.bag.topics[topic].count
        return n if n >= 0 else None

    @property
    def damage(self) -> str | None:
        return self.bag.damage

    def close(self) -> None:
        super().close()
        self.bag.close()

    def messages(self, topics: set[str]) -> Iterator[RawMessage]:
        """The raw messages of `topics` until the end, the bag's damage, or close()."""
        for message in self.bag.messages(topics):
            if self.closed:
                return
            yield message

    def decode(self, message: RawMessage, msgtype: str) -> Any:
        try:
            return self.bag.deserialize(message.raw, msgtype)
        except DamagedMessage as exc:
            raise DamagedMessage(f"{self.path}: {message.topic}: {exc}") from None

    def damaged(self, frame_number: int | None, exc: DamagedMessage) -> None:
        """A garbled message: its frame ledgered as damaged (by `frame_number`, when known; else counted in
        counters["damaged_message"]) and the bag read on. In a bag read record by record after damage it ends
        the readable part instead (its bytes may be the zeros standing in for a missing page)."""
        if self.bag.recovering:
            raise exc
        why = str(exc) if str(exc).startswith(str(self.path)) else f"{self.path}: {exc}"
        if frame_number is None:
            self.counters["damaged_message"] += 1
            log.warning("%s", why)
        else:
            self.reject(frame_number % (1 << 32), f"damaged: {why}")

    def check_sizes(self, where: str, **planes: tuple[int, int]) -> None:
        """BagError when the named (H, W) shapes differ."""
        if len(set(planes.values())) > 1:
            raise BagError(f"{where}: sizes differ: " + ", ".join(
                f"{name.replace('_', ' ')} {w}x{h}" for name, (h, w) in planes.items()))

    @abstractmethod
    def frames(self) -> Iterator[Frame]:
        """The bag's frames in order (BagError at the first one tofd cannot use)."""

    def __iter__(self) -> Iterator[Frame]:
        """`frames()`, then the unreadable rest of a damaged bag ledgered as one rejected frame after the last one
        delivered. In a bag read record by record after damage, a message that does not decode is part of the
        damage (its bytes may be the zeros standing in for a missing page), not an error."""
        counter = 0
        try:
            for frame in self.frames():
                counter = frame.frame_counter + 1
                yield frame
        except BagError as exc:
            if not self.bag.recovering:
                raise exc if str(exc).startswith(str(self.path)) else BagError(f"{self.path}: {exc}") from None
            self.bag.damage = f"{self.bag.damage or 'damaged'}; {exc}"
        if self.bag.damage is not None:
            self.reject(counter, f"damaged: {self.path}: the rest is unreadable ({self.bag.damage})")


class RejectsAfter(FrameSource):
    """`source`'s frames, then the frames an earlier stage rejected: what importing a bag ledgered (its damaged
    tail) reaches the pipeline's ledger when the imported recording is replayed. Counters and other attributes
    are `source`'s."""

    def __init__(self, source: FrameSource, rejected: list[Rejected]) -> None:
        super().__init__()
        self.source, self._pending = source, list(rejected)
        self.counters = source.counters

    def __iter__(self) -> Iterator[Frame]:
        for frame in self.source:
            self._rejected.extend(self.source.take_rejected())
            yield frame
        self._rejected.extend(self.source.take_rejected())
        for item in self._pending:
            self.reject(item.frame_counter, item.reason)
        self._pending.clear()

    def close(self) -> None:
        super().close()
        self.source.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.source, name)
