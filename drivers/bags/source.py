"""What every bag-backed frame source shares: the open bag, the range conversions, the calibration check, the
account of a damaged tail, and what the file says about the device, its signal and its settings."""

from __future__ import annotations

import json
import logging
from abc import abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tofd.drivers.bags.scan import BagError, BagReader, DamagedMessage, RawMessage
from tofd.drivers.frame import COUNTER_LIMIT, PERIOD_FRAMES, AmplitudeKind, Frame, SensorInfo
from tofd.drivers.source import FrameSource, Rejected, SourceReport

log = logging.getLogger(__name__)


class BagSource(FrameSource):
    """A FrameSource reading a bag through tofd.drivers.bags.scan.BagReader.

    After iteration, `intrinsics` is the calibration of the frames (None when none was delivered), `report` says
    why reading stopped early (reason "damaged", detail the bag's damage) and `settings` holds what the file says
    about the device and how it was set (units, rates, options), for the provenance of an imported recording;
    `expected_frames` is the number of range images (an upper bound on the frames). Frames
    without SR3000 registers carry it as `sensor` (tofd.drivers.frame.SensorInfo), with `amplitude_kind`, the raw
    planes' units (note_signal) and the frame period from the first PERIOD_FRAMES device timestamps.
    """

    amplitude_kind: AmplitudeKind = "ir"
    """What the source's amplitude image is."""
    unambiguous_range_m: float | None = None
    """The range at which the phase wraps, when the file says (None: unknown)."""

    def __init__(self, path: str | Path, bag: BagReader | None = None) -> None:
        """`bag`: the bag at `path` already open (its reader is the source's from then on)."""
        super().__init__()
        self.path = Path(path)
        self.bag = bag or BagReader(self.path)
        self.range_messages: int | None = None
        """Range images in the bag (an upper bound on the frames; None when unknown)."""
        self._ended = False  # iteration reached the end of the bag or its damage
        self._last_good: int | None = None  # counter of the last frame delivered
        self.sensor: SensorInfo | None = None
        """The frames' signal and settings (known once iteration started)."""
        self._signal: tuple[float, int | None, float | None] | None = None

    def message_count(self, topic: str) -> int | None:
        """Messages of `topic` in the bag, None when unknown (a damaged sqlite3 bag read row by row)."""
        n = self.bag.topics[topic].count
        return n if n >= 0 else None

    @property
    def expected_frames(self) -> int | None:
        return self.range_messages

    @property
    def report(self) -> SourceReport:
        if self.bag.damage is not None:
            return SourceReport("damaged", self.bag.damage, self._last_good)
        return SourceReport("end" if self._ended else None, "", self._last_good)

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
            self.reject(frame_number % COUNTER_LIMIT, f"damaged: {why}")

    def check_sizes(self, where: str, **planes: tuple[int, int]) -> None:
        """BagError when the named (H, W) shapes differ."""
        if len(set(planes.values())) > 1:
            raise BagError(f"{where}: sizes differ: " + ", ".join(
                f"{name.replace('_', ' ')} {w}x{h}" for name, (h, w) in planes.items()))

    def note_signal(self, depth: np.ndarray, amplitude: np.ndarray, metres_per_unit: float, invalid: int = 0) -> None:
        """Remember what the first frame's raw images say: metres per depth value and the `invalid` value (float
        depth: metres, none) and the amplitude's full scale (None for float amplitude)."""
        if self._signal is None:
            floating = depth.dtype.kind == "f"
            self._signal = (1.0 if floating else metres_per_unit, None if floating else invalid,
                            None if amplitude.dtype.kind == "f" else float(np.iinfo(amplitude.dtype).max))

    def _sensor_info(self, frames: list[Frame]) -> SensorInfo:
        """The SensorInfo of the frames, from their device timestamps, note_signal and `settings`."""
        unit, invalid, full_scale = self._signal or (1.0, None, None)
        steps = np.diff([f.timestamp_us for f in frames])
        period = float(np.median(steps)) / 1e6 if len(steps) and np.median(steps) > 0 else None
        return SensorInfo(depth_unit_m=unit, amplitude=self.amplitude_kind, invalid_value=invalid,
                          amplitude_full_scale=full_scale, unambiguous_range_m=self.unambiguous_range_m,
                          frame_period_s=period,
                          settings={k: v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str)
                                    for k, v in self.settings.items()})

    def _release(self, head: list[Frame]) -> Iterator[Frame]:
        """The buffered first frames, with the sensor info they determine (frames with SR3000 registers keep
        none)."""
        if head and self.sensor is None:
            self.sensor = self._sensor_info(head)
        for frame in head:
            frame.sensor = self.sensor if frame.registers is None else None
            yield frame
        head.clear()

    def _with_sensor(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        """`frames`, held back until the first PERIOD_FRAMES give the frame period, each with its sensor info."""
        head: list[Frame] = []
        try:
            for frame in frames:
                head.append(frame)
                if self.sensor is not None or len(head) == PERIOD_FRAMES:
                    yield from self._release(head)
        except Exception:
            yield from self._release(head)  # the frames read before an error are delivered first
            raise
        yield from self._release(head)

    @abstractmethod
    def frames(self) -> Iterator[Frame]:
        """The bag's frames in order (BagError at the first one tofd cannot use)."""

    def __iter__(self) -> Iterator[Frame]:
        """`frames()`, then the unreadable rest of a damaged bag ledgered as one rejected frame after the last one
        delivered. In a bag read record by record after damage, a message that does not decode is part of the
        damage (its bytes may be the zeros standing in for a missing page), not an error."""
        counter = 0
        try:
            for frame in self._with_sensor(self.frames()):
                counter, self._last_good = frame.frame_counter + 1, frame.frame_counter
                yield frame
        except BagError as exc:
            if not self.bag.recovering:
                raise exc if str(exc).startswith(str(self.path)) else BagError(f"{self.path}: {exc}") from None
            self.bag.damage = f"{self.bag.damage or 'damaged'}; {exc}"
        self._ended = not self.closed
        if self.bag.damage is not None:
            self.reject(counter, f"damaged: {self.path}: the rest is unreadable ({self.bag.damage})")


class RejectsAfter(FrameSource):
    """`source`'s frames, then the frames an earlier stage rejected: what importing a bag ledgered (its damaged
    tail) reaches the pipeline's ledger when the imported recording is replayed. Counters, intrinsics, settings,
    expected frames and report are `source`'s."""

    def __init__(self, source: FrameSource, rejected: list[Rejected]) -> None:
        super().__init__()
        self.source, self._pending = source, list(rejected)
        self.counters, self.intrinsics, self.settings = source.counters, source.intrinsics, source.settings

    @property
    def expected_frames(self) -> int | None:
        return self.source.expected_frames

    @property
    def report(self) -> SourceReport:
        return self.source.report

    def __iter__(self) -> Iterator[Frame]:
        for frame in self.source:
            self._rejected.extend(self.source.take_rejected())
            self.intrinsics = self.source.intrinsics
            yield frame
        self._rejected.extend(self.source.take_rejected())
        self.intrinsics, self.settings = self.source.intrinsics, self.source.settings
        for item in self._pending:
            self.reject(item.frame_counter, item.reason, item.frames)
        self._pending.clear()

    def close(self) -> None:
        super().close()
        self.source.close()
