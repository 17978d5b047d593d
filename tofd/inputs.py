"""Every input tofd reads as a FrameSource, what one says about itself (for `tofd info` and `tofd export`), and
its frames written as a tofd recording (for `tofd import`, and `tofd replay` of a bag).

open_reader opens what tofd.drivers.opener recognises (the one table of input kinds), naming an input it cannot
read in a UsageError; describe_input describes a kind whose file has a header worth showing; everything else
(frames, duration, rate, camera, intrinsics, damage) is read from the frames and the source's counters, the same
for every kind.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tofd.drivers.frame import DeviceInfo, Frame, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import FrameSource
from tofd.errors import input_error

if TYPE_CHECKING:
    from tofd.drivers.bags.driver_bag import RangeOptions
    from tofd.drivers.opener import InputFormat
    from tofd.drivers.recording.reader import RecordingInfo
    from tofd.drivers.recording.replay import ReplaySource
    from tofd.drivers.source import Rejected
    from tofd.progress import Progress


@dataclass(frozen=True, slots=True)
class InputDescription:
    """What kind of file an input is: a one-line description and its format version ("" where it has none)."""

    kind: str  # e.g. "tofd recording (MCAP)", "ROS 2 bag"
    version: str
    details: tuple[tuple[str, str], ...] = ()  # more (name, value) lines: writer, creation time, storage


@dataclass(slots=True)
class InputSummary:
    """An input read to its end: frame count, device-clock span, camera, intrinsics and lens, depth unit, damage."""

    path: Path
    format: InputDescription
    frames: int = 0
    first_counter: int | None = None
    last_counter: int | None = None
    first_us: int | None = None  # device timestamps, microseconds
    last_us: int | None = None
    device: DeviceInfo | None = None
    intrinsics: Intrinsics | None = None
    sensor: SensorInfo | None = None  # a camera other than the SR3000: its signal and settings
    registers: Registers | None = None  # the SR3000's register settings
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
            self.sensor, self.registers = frame.sensor, frame.registers
        self.last_counter, self.last_us = frame.frame_counter, frame.timestamp_us

    @property
    def depth_unit_m(self) -> float | None:
        """Metres per raw depth value in the file (1.0: float metres; the SR3000's raw distance unit at its
        modulation frequency); None when the frames say neither."""
        if self.sensor is not None:
            return self.sensor.depth_unit_m
        return None if self.registers is None else self.registers.depth_unit_m

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
                "lens": None if self.intrinsics is None else {"model": self.intrinsics.distortion_model,
                                                              "coefficients": self.intrinsics.coefficients()},
                "depth_unit_m": self.depth_unit_m,
                "damage": {"rejected": dict(self.rejected), "stopped": self.stopped or None}}


def describe_input(path: Path, fmt: InputFormat, source: FrameSource) -> InputDescription:
    """What kind of file the input `path` of format `fmt` (open_reader's) is; a ROS bag's storage, a tofd
    recording's format version, writer and creation time from its header."""
    from tofd.drivers import opener
    from tofd.drivers.recording.replay import ReplaySource

    if fmt == opener.ROSBAG:
        kind = "ROS 1 bag" if path.suffix == ".bag" else "ROS 2 bag"
        storage = "mcap" if path.suffix == ".mcap" or any(path.glob("*.mcap")) else "sqlite3"
        return InputDescription(kind, "", () if kind == "ROS 1 bag" else (("storage", storage),))
    if not isinstance(source, ReplaySource) or source.info is None:
        return InputDescription(fmt.description, "")
    info = source.info
    created = datetime.fromtimestamp(info.created_wall_s, UTC).strftime("%Y-%m-%d %H:%M:%S UTC") \
        if math.isfinite(info.created_wall_s) else "unknown"
    return InputDescription("tofd recording (MCAP)", str(info.format_version),
                            (("written by", f"tofd {info.software_version}"), ("created", created)))


def _count_rejected(source: FrameSource, summary: InputSummary) -> None:
    for rejected in source.take_rejected():
        summary.rejected[rejected.reason.split(":")[0]] += rejected.frames


def frames_with_rejects(source: FrameSource, summary: InputSummary) -> Iterator[Frame]:
    """The source's frames; the frames it rejects (damage) are counted in summary.rejected on the way, and why
    it stopped early (the source's report) in summary.stopped."""
    for frame in source:
        _count_rejected(source, summary)
        yield frame
    _count_rejected(source, summary)
    summary.counters = {k: v for k, v in source.counters.items() if v}
    report = source.report
    if report.stopped_early:
        summary.stopped = f"{report.reason}: {report.detail}"


def summarize(path: Path, bag_options: RangeOptions) -> InputSummary:
    """Read the input at `path` to its end (InputSummary); UsageError when it cannot be opened."""
    fmt, source = open_reader(path, bag_options)
    summary = InputSummary(path, describe_input(path, fmt, source))
    with source:
        for frame in frames_with_rejects(source, summary):
            summary.add(frame)
    return summary


def open_reader(path: Path, bag_options: RangeOptions) -> tuple[InputFormat, FrameSource]:
    """The format of `path` and a lossless FrameSource on it (tofd.drivers.opener.open_input); UsageError names an
    input that cannot be read, and ROS bag options given for another kind of file."""
    from tofd.drivers.bags.driver_bag import RangeOptions
    from tofd.drivers.opener import open_input
    from tofd.drivers.source import DriverError

    try:
        fmt, source = open_input(path, bag_options)
    except (DriverError, OSError, ValueError) as exc:
        raise input_error(path, exc) from None
    if fmt.read_as != "bag" and bag_options != RangeOptions():
        source.close()
        raise input_error(path, ValueError(f"a {fmt.description}: the ROS bag options are for ROS bags"))
    return fmt, source


def open_recording(path: Path, **replay: Any) -> tuple[ReplaySource, RecordingInfo]:
    """A ReplaySource on the tofd recording `path` (`replay`: its mode, speed, loop and seek) and its header;
    UsageError names a file that cannot be replayed or whose header is damaged."""
    from tofd.drivers.recording.replay import ReplaySource
    from tofd.drivers.source import DriverError

    try:
        source = ReplaySource(path, **replay)
    except (DriverError, OSError, ValueError) as exc:
        raise input_error(path, exc) from None
    if source.info is None:
        source.close()
        raise input_error(path, ValueError(source.header_problem))
    return source, source.info


def convert(path: Path, fmt: InputFormat, source: FrameSource, bag_options: RangeOptions, out: Path,
            progress: Callable[[int | None], Progress], rejected: list[Rejected] | None = None) -> str:
    """Write the frames of `source` (open_reader's, on the bag or .mkv `path` of format `fmt`, with `bag_options`)
    to the tofd recording `out`, renamed into place when complete, with the progress bar `progress(total)` makes;
    returns what was written, e.g. "12 frames of 176x144". The frames the source rejected (a damaged tail) are
    added to `rejected`. UsageError names a bad input."""
    import dataclasses

    from tofd.drivers.bags.scan import BagError
    from tofd.drivers.recording.writer import RecordingWriter
    from tofd.drivers.source import DriverError
    from tofd.errors import UsageError
    from tofd.outputs import AtomicFile

    provenance = {"import": {"bag": str(path), **dataclasses.asdict(bag_options), "source": source.settings}
                  if fmt.read_as == "bag" else {"file": str(path), "format": fmt.name}}
    bar = progress(source.expected_frames)
    # the writer opens the temp file by name; AtomicFile renames it to `out` only when every frame is in
    with source, AtomicFile(out, "wb") as target:
        try:
            with RecordingWriter(target.tmp_path, config=provenance, fsync_interval_s=None) as writer:
                for frame in source:
                    writer.write(frame)
                    bar.update(writer.frames_written)
        except (BagError, DriverError) as exc:
            raise UsageError(str(exc)) from None
        finally:
            bar.done()
        unpaired = _unpaired(source.counters)
        intrinsics = source.intrinsics
        damage = source.report.detail if source.report.stopped_early else ""
        if intrinsics is None or not writer.frames_written:
            why = f"; {damage}" if damage else ""
            raise UsageError(f"{path}: no header stamp has a range image, an amplitude image and a camera_info "
                             f"({unpaired or 'its topics are empty'}{why}); nothing written" if fmt.read_as == "bag"
                             else f"{path}: no frame could be read; nothing written")
    lost_frames = source.take_rejected()
    lost = sum(r.frames for r in lost_frames)
    if rejected is not None:
        rejected.extend(lost_frames)
    skipped = "; ".join(filter(None, [unpaired, f"{lost} frames lost or damaged (see the log)" if lost else ""]))
    size = f"{intrinsics.width}x{intrinsics.height}"
    damaged = f"; damaged, the rest unread: {damage}" if damage else ""
    return f"{writer.frames_written} frames of {size}" + (f"; skipped {skipped}" if skipped else "") + damaged


def _unpaired(counters: dict[str, int]) -> str:
    """The messages left without the others of their stamp and those that did not decode, e.g. "3 range,
    1 camera_info messages unpaired; 1 garbled message skipped"."""
    parts = [f"{n} {key.removeprefix('unpaired_')}" for key, n in sorted(counters.items())
             if key.startswith("unpaired_") and n]
    garbled = counters.get("damaged_message", 0)
    return "; ".join(filter(None, [f"{', '.join(parts)} messages unpaired" if parts else "",
                                   f"{garbled} garbled message{'s' * (garbled != 1)} skipped" if garbled else ""]))
