"""Replay of tofd recordings: ReplaySource (a FrameSource), read_recording_info, iter_frames.

Reading is sequential and needs neither MCAP's summary nor its footer, so a recording whose writer was
killed replays up to its last complete frame. Every chunk's CRC is checked; the first record that is cut
short, fails its CRC or does not parse ends the stream: everything before it is replayed and the source
says where and why it stopped (`stopped_reason`, `stop_detail`, `last_good_counter`, counters["corrupt_tail"]).
"""

from __future__ import annotations

import json
import logging
import math
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Literal

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Message, Metadata
from mcap.stream_reader import breakup_chunk
from mcap.writer import MCAP0_MAGIC

from drivers.frame import DeviceInfo, Frame, Registers
from drivers.intrinsics import Intrinsics
from drivers.recording import format as fmt
from drivers.source import DriverError, FrameSource

log = logging.getLogger(__name__)

MAX_RECORD_BYTES = 256 << 20
"""Largest record the reader accepts; a larger length field is corruption (a frame chunk is ~0.1 MB)."""

StopReason = Literal["end", "truncated", "corrupt"]
_DATA_OPCODES = frozenset({Opcode.HEADER, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.CHUNK, Opcode.MESSAGE_INDEX})
"""Top-level records a tofd recording has before its end-of-data record (anything else there is damage)."""


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """What a recording says about itself (its first records; frame_count only if the file was closed)."""

    path: Path
    format_version: int
    software_version: str
    created_wall_s: float
    intrinsics: Intrinsics | None  # None when the recording holds no frame
    device: DeviceInfo | None
    registers: Registers | None
    config: dict | None  # the service config it was made with (attachment config.json)
    frame_count: int | None  # from MCAP's statistics; None when the writer did not finish (crash)


class RecordingReader:
    """Sequential reader of one pass over a recording's records.

    Iterating `frames()` yields the decoded frames in file order; metadata and attachments seen on the
    way are collected in `metadata` and `attachments`. When iteration ends, `reason`/`detail`/`offset`
    say why and where: "end" (the writer finished), "truncated" (file ends early: killed writer or cut
    file) or "corrupt" (a CRC mismatch or an unparsable record).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 (closed by close())
        except OSError as exc:
            raise DriverError(f"cannot open recording {self.path}: {exc.strerror}") from None
        self.file_size = self.path.stat().st_size
        magic = self._file.read(len(MCAP0_MAGIC))
        if magic != MCAP0_MAGIC:
            self._file.close()
            raise DriverError(f"{self.path} is not a tofd recording (no MCAP magic at its start)")
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.reason: StopReason | None = None
        self.detail = ""
        self.offset = len(MCAP0_MAGIC)  # end of the last good record, bytes
        self._frame_channels: set[int] = set()
        self._previous_opcode: int | None = None

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _stop(self, reason: StopReason, detail: str) -> None:
        self.reason, self.detail = reason, detail

    def _record(self) -> tuple[int, bytes] | None:
        """The next record (opcode, body), or None after recording why reading must stop."""
        head = self._file.read(9)
        if len(head) < 9:
            where = "at a record boundary" if not head else "inside a record header"
            self._stop("truncated", f"file ends {where} at byte {self.offset + len(head)} without MCAP's "
                                    "end-of-data record (the writer did not finish: killed, crashed or cut)")
            return None
        opcode, length = struct.unpack("<BQ", head)
        if length > MAX_RECORD_BYTES:
            self._stop("corrupt", f"record at byte {self.offset} claims {length} bytes (opcode {opcode:#04x})")
            return None
        body = self._file.read(length)
        if len(body) < length:
            self._stop("truncated", f"file ends at byte {self.file_size} inside a record that starts at byte "
                                    f"{self.offset} and needs {length} bytes")
            return None
        return opcode, body

    def _parse(self, opcode: int, body: bytes) -> list[Frame]:
        """Frames of one top-level record (raises on corruption)."""
        stream = ReadDataStream(BytesIO(body))
        if opcode == Opcode.CHUNK:
            chunk = Chunk.read(stream)
            if stream.count != len(body):  # the writer never pads: a longer record is a damaged length
                raise fmt.FormatError(f"chunk record of {len(body)} bytes holds {stream.count}")
            frames = []
            for rec in breakup_chunk(chunk, validate_crc=True):
                if isinstance(rec, Channel):
                    if rec.topic == fmt.FRAME_TOPIC and rec.message_encoding == fmt.FRAME_ENCODING:
                        self._frame_channels.add(rec.id)
                elif isinstance(rec, Message) and rec.channel_id in self._frame_channels:
                    frames.append(fmt.decode_frame(rec.data))
            return frames
        if opcode == Opcode.METADATA:
            meta = Metadata.read(stream)
            self.metadata[meta.name] = meta.metadata
        elif opcode == Opcode.ATTACHMENT:
            if zlib.crc32(body[:-4]) != struct.unpack("<I", body[-4:])[0]:
                raise fmt.FormatError("attachment CRC mismatch")
            att = Attachment.read(stream)
            self.attachments[att.name] = att.data
        elif opcode not in _DATA_OPCODES:
            raise fmt.FormatError(f"record opcode {opcode:#04x} does not belong in a recording's data section")
        elif opcode == Opcode.MESSAGE_INDEX and self._previous_opcode != Opcode.CHUNK:
            raise fmt.FormatError("message index without its chunk before it (a damaged chunk record?)")
        elif opcode == Opcode.HEADER and self.offset != len(MCAP0_MAGIC):
            raise fmt.FormatError("a second header record")
        return []

    def frames(self) -> Iterator[Frame]:
        """Frames in file order, until the end of data or the first bad record."""
        while self.reason is None:
            rec = self._record()
            if rec is None:
                return
            opcode, body = rec
            if opcode == Opcode.DATA_END:
                self._stop("end", f"end of data at byte {self.offset} of {self.file_size}")
                return
            try:
                frames = self._parse(opcode, body)
            except Exception as exc:  # noqa: BLE001 (any failure to parse these bytes is corruption)
                self._stop("corrupt", f"bad record at byte {self.offset} (opcode {opcode:#04x}): "
                                      f"{type(exc).__name__}: {exc}")
                return
            self.offset += 9 + len(body)
            self._previous_opcode = opcode
            yield from frames


def _info_from(reader: RecordingReader, frame_count: int | None) -> RecordingInfo:
    rec = reader.metadata.get(fmt.META_RECORDING)
    if rec is None:
        raise DriverError(f"{reader.path} is not a tofd recording (no {fmt.META_RECORDING} metadata)")

    def meta(cls: type, name: str) -> object:
        data = reader.metadata.get(name)
        return None if data is None else fmt.from_metadata(cls, data)

    config_bytes = reader.attachments.get(fmt.CONFIG_ATTACHMENT)
    return RecordingInfo(
        path=reader.path,
        format_version=int(rec.get("format_version", "0")),
        software_version=rec.get("software_version", "unknown"),
        created_wall_s=float(rec.get("created_wall_s", "nan")),
        intrinsics=meta(Intrinsics, fmt.META_INTRINSICS),  # type: ignore[arg-type]
        device=meta(DeviceInfo, fmt.META_DEVICE),  # type: ignore[arg-type]
        registers=meta(Registers, fmt.META_REGISTERS),  # type: ignore[arg-type]
        config=None if config_bytes is None else json.loads(config_bytes),
        frame_count=frame_count,
    )


def _frame_count(path: Path) -> int | None:
    """Frame count from MCAP's summary, or None if the file has no intact summary (writer did not finish)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 (a missing or damaged summary only means: count unknown)
        return None
    return None if summary is None or summary.statistics is None else summary.statistics.message_count


def read_recording_info(path: str | Path) -> RecordingInfo:
    """The header of a recording: software version, intrinsics, device, registers, config, frame count.

    Raises DriverError if the file is not a tofd recording or its header records are damaged (the frames
    may still replay: each carries its own intrinsics, device and registers).
    """
    with RecordingReader(path) as reader:
        next(reader.frames(), None)  # metadata and attachments precede the first frame
        try:
            return _info_from(reader, _frame_count(reader.path))
        except (ValueError, TypeError, KeyError) as exc:  # FormatError and JSON errors are ValueErrors
            raise DriverError(f"{reader.path}: damaged recording header: {exc}") from None


def _check_counter(name: str, value: int | None) -> None:
    if value is not None and (not isinstance(value, int) or value < 0):
        raise ValueError(f"{name}: expected a frame counter >= 0, got {value!r}")


class ReplaySource(FrameSource):
    """Frames of a recording, as a FrameSource.

    mode="lossless": every frame in the range, as fast as the consumer takes them.
    mode="realtime": frames at their recorded pace (host receive times) divided by `speed`; when the
    consumer falls behind, frames whose successor is already due are skipped and counted in
    counters["replay_dropped"].
    The range is the frames with start <= frame_counter < stop (None = open end); `seek` starts the first
    pass at the first frame whose counter is >= seek; `loop` replays the range again from `start` until
    close() (counters["replay_loops"] counts restarts). Iteration always ends at the end of the file
    unless looping. A truncated or corrupt file replays its readable prefix; then `stopped_reason`
    ("end", "truncated" or "corrupt"), `stop_detail`, `last_good_counter` say where it stopped, a warning is
    logged and counters["corrupt_tail"] is 1.
    """

    def __init__(self, path: str | Path, *, mode: Literal["lossless", "realtime"] = "lossless", speed: float = 1.0,
                 loop: bool = False, seek: int | None = None, start: int | None = None,
                 stop: int | None = None) -> None:
        super().__init__()
        if mode not in ("lossless", "realtime"):
            raise ValueError(f"mode: expected 'lossless' or 'realtime', got {mode!r}")
        if not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed: expected a finite factor > 0, got {speed!r}")
        for name, value in (("seek", seek), ("start", start), ("stop", stop)):
            _check_counter(name, value)
        if start is not None and stop is not None and stop <= start:
            raise ValueError(f"stop: must be greater than start ({start}), got {stop}")
        self.path = Path(path)
        RecordingReader(self.path).close()  # fail now on a missing or foreign file
        self.mode, self.speed, self.loop = mode, float(speed), loop
        self.seek, self.start, self.stop = seek, start, stop
        self.stopped_reason: StopReason | None = None
        self.stop_detail = ""
        self.last_good_counter: int | None = None  # counter of the last frame read intact from the file
        self.frames_read = 0  # intact frames read from the file in the first pass

    def _in_range(self, counter: int) -> bool:
        return (self.start is None or counter >= self.start) and (self.stop is None or counter < self.stop)

    def _pass(self, seek: int | None, first: bool) -> Iterator[Frame]:
        """Frames of one pass over the file, within the range, from the first counter >= seek."""
        seeking = seek is not None
        with RecordingReader(self.path) as reader:
            for frame in reader.frames():
                if first:
                    self.frames_read += 1
                    self.last_good_counter = frame.frame_counter
                if self.closed:
                    return
                if seeking and frame.frame_counter < seek:
                    continue
                seeking = False
                if self._in_range(frame.frame_counter):
                    yield frame
            if first:
                self._report(reader)

    def _report(self, reader: RecordingReader) -> None:
        self.stopped_reason, self.stop_detail = reader.reason, reader.detail
        if reader.reason != "end":
            self.counters["corrupt_tail"] += 1
            log.warning("%s: replayed the readable prefix (%d frames, last frame counter %s); %s: %s",
                        self.path, self.frames_read, self.last_good_counter, reader.reason, reader.detail)

    def _paced(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        """Frames at their recorded pace / speed, skipping those overtaken while the consumer was busy."""
        t0 = r0 = prev_r = 0.0
        current = next(frames, None)
        rebase = True
        while current is not None:
            following = next(frames, None)
            now = time.monotonic()
            r = current.host_monotonic_s
            if rebase or r < prev_r:  # first frame, or recorded time went backwards: restart the clock
                t0, r0, rebase = now, r, False
            prev_r = r
            if following is not None and t0 + (following.host_monotonic_s - r0) / self.speed <= now:
                self.counters["replay_dropped"] += 1
                current = following
                continue
            wait = t0 + (r - r0) / self.speed - now
            if wait > 0 and self._closed.wait(wait):
                return
            yield current
            current = following

    def __iter__(self) -> Iterator[Frame]:
        """The frames (iterate from one thread at a time; close() may come from any thread)."""
        first = True
        while not self.closed:
            frames = self._pass(self.seek if first else self.start, first)
            if self.mode == "realtime":
                frames = self._paced(frames)
            yielded = False
            for frame in frames:
                if self.closed:
                    return
                yielded = True
                self.counters["frames"] += 1
                yield frame
            if self.closed or not self.loop or (not yielded and not (first and self.seek is not None)):
                return
            first = False
            self.counters["replay_loops"] += 1


def iter_frames(path: str | Path, *, start: int | None = None, stop: int | None = None) -> Iterator[Frame]:
    """Every frame of a recording in order (lossless), e.g. as evaluation input with ground truth."""
    with ReplaySource(path, start=start, stop=stop) as source:
        yield from source
