"""Every input tofd reads as a FrameSource, and what one says about itself (for `tofd info` and `tofd export`).

open_input opens what tofd.drivers.opener recognises (the one table of input kinds); a kind whose file has a header
worth showing gets a branch there that describes it; everything else (frames, duration, rate, camera,
intrinsics, damage) is read from the frames and the source's counters, the same for every kind.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from tofd.drivers.frame import DeviceInfo, Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import FrameSource

if TYPE_CHECKING:
    from tofd.drivers.bags.driver_bag import RangeOptions


@dataclass(frozen=True, slots=True)
class InputDescription:
    """What kind of file an input is: a one-line description and its format version ("" where it has none)."""

    kind: str  # e.g. "tofd recording (MCAP)", "ROS 2 bag"
    version: str
    details: tuple[tuple[str, str], ...] = ()  # more (name, value) lines: writer, creation time, storage


@dataclass(slots=True)
class InputSummary:
    """An input read to its end: frame count, device-clock span, camera, intrinsics, damage."""

    path: Path
    format: InputDescription
    frames: int = 0
    first_counter: int | None = None
    last_counter: int | None = None
    first_us: int | None = None  # device timestamps, microseconds
    last_us: int | None = None
    device: DeviceInfo | None = None
    intrinsics: Intrinsics | None = None
    rejected: Counter[str] = field(default_factory=Counter)  # frames the source did not deliver, by reason class
    counters: dict[str, int] = field(default_factory=dict)  # the source's fault counters
    stopped: str = ""  # why reading stopped early (a damaged or truncated file), "" when it read to the end

    @property
    def duration_s(self) -> float:
        """Seconds between the first and the last frame's device timestamps (0 with fewer than two frames)."""
        return 0.0 if self.first_us is None or self.last_us is None else (self.last_us - self.first_us) / 1e6

    @property
    def rate_hz(self) -> float:
        """Mean frames per second over the duration (NaN with fewer than two frames)."""
        return (self.frames - 1) / self.duration_s if self.frames > 1 and self.duration_s > 0 else math.nan

    def add(self, frame: Frame) -> None:
        """Count one delivered frame."""
        self.frames += 1
        if self.first_counter is None:
            self.first_counter, self.first_us = frame.frame_counter, frame.timestamp_us
            self.device, self.intrinsics = frame.device, frame.intrinsics
        self.last_counter, self.last_us = frame.frame_counter, frame.timestamp_us

    @property
    def damaged(self) -> bool:
        return bool(self.rejected or self.stopped)

    def to_dict(self) -> dict:
        """JSON-ready: every field, with duration_s and rate_hz (None when undefined)."""
        rate = self.rate_hz
        return {"path": str(self.path), "format": self.format.kind, "format_version": self.format.version,
                "details": dict(self.format.details), "frames": self.frames,
                "frame_counters": [self.first_counter, self.last_counter], "duration_s": self.duration_s,
                "rate_hz": None if math.isnan(rate) else rate,
                "camera": None if self.device is None else {"model": self.device.model, "serial": self.device.serial,
                                                            "firmware": self.device.firmware,
                                                            "backend": self.device.backend},
                "intrinsics": None if self.intrinsics is None else self.intrinsics.to_dict(),
                "damage": {"rejected": dict(self.rejected), "stopped": self.stopped or None}}


def open_input(path: Path, bag_options: RangeOptions | None = None) -> tuple[FrameSource, InputDescription]:
    """A lossless FrameSource on `path` and its format, recognised by tofd.drivers.opener (`bag_options`: a ROS bag's
    topics and range encoding); DriverError (or OSError) when it cannot be read."""
    from tofd.drivers.opener import identify
    from tofd.drivers.source import DriverError

    try:
        fmt = identify(path)
    except ValueError as exc:
        raise DriverError(str(exc)) from None
    if fmt.read_as == "bag":
        from tofd.drivers.bags.opener import open_bag

        source = open_bag(path, bag_options)
        if fmt.name != "rosbag":  # a vendor SDK's recording
            return source, InputDescription(fmt.description, "")
        kind = "ROS 1 bag" if path.suffix == ".bag" else "ROS 2 bag"
        storage = "mcap" if path.suffix == ".mcap" or any(path.glob("*.mcap")) else "sqlite3"
        return source, InputDescription(kind, "", () if kind == "ROS 1 bag" else (("storage", storage),))
    if fmt.read_as == "source" and fmt.open is not None:
        return fmt.open(path), InputDescription(fmt.description, "")
    from tofd.drivers.recording.reader import read_recording_info
    from tofd.drivers.recording.replay import ReplaySource

    info = read_recording_info(path)
    created = datetime.fromtimestamp(info.created_wall_s, UTC).strftime("%Y-%m-%d %H:%M:%S UTC") \
        if math.isfinite(info.created_wall_s) else "unknown"
    return ReplaySource(path), InputDescription("tofd recording (MCAP)", str(info.format_version),
                                           (("written by", f"tofd {info.software_version}"), ("created", created)))


def _count_rejected(source: FrameSource, summary: InputSummary) -> None:
    for rejected in source.take_rejected():
        summary.rejected[rejected.reason.split(":")[0]] += rejected.frames


def frames_with_rejects(source: FrameSource, summary: InputSummary) -> Iterator[Frame]:
    """The source's frames; the frames it rejects (damage) are counted in summary.rejected on the way, and why
    it stopped early (a replayed recording's stopped_reason) in summary.stopped."""
    for frame in source:
        _count_rejected(source, summary)
        yield frame
    _count_rejected(source, summary)
    summary.counters = {k: v for k, v in source.counters.items() if v}
    reason = getattr(source, "stopped_reason", None)
    if reason not in (None, "end"):
        summary.stopped = f"{reason}: {getattr(source, 'stop_detail', '')}"


def summarize(path: Path, bag_options: RangeOptions | None = None) -> InputSummary:
    """Read the input at `path` to its end (InputSummary); DriverError/OSError when it cannot be opened."""
    source, fmt = open_input(path, bag_options)
    summary = InputSummary(path, fmt)
    with source:
        for frame in frames_with_rejects(source, summary):
            summary.add(frame)
    return summary
