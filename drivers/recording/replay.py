"""Replay of tofd recordings: ReplaySource (a FrameSource), read_recording_info, iter_frames.

Reading is sequential and needs neither MCAP's summary nor its footer, so a recording whose writer was
killed replays up to its last complete frame. Every chunk's CRC is checked (a chunk without one is
refused); at a record that is cut short, fails its CRC or does not parse, the reader resyncs at the next
intact chunk, so every readable frame is replayed. Frames lost to damage (by counter), invalid frames
(drivers.frame.frame_problem) and duplicated frames (same counter and device timestamp) are rejected
through FrameSource.reject for the pipeline's drop ledger. Where the file ends early or has no intact
chunk after damage, the source says why (`stopped_reason`, `stop_detail`, `last_good_counter`,
counters["corrupt_tail"]).
"""

from __future__ import annotations

import json
import logging
import math
import mmap
import struct
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Literal

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import MCAP0_MAGIC

from drivers.frame import DeviceInfo, Frame, Registers, frame_problem
from drivers.intrinsics import Intrinsics
from drivers.recording import format as fmt
from drivers.recording import format_v1
from drivers.source import DriverError, FrameSource

log = logging.getLogger(__name__)

MAX_LOST_FRAMES = 1 << 20
"""Most frames one damaged stretch is taken to have destroyed (a larger counter jump is not a loss count)."""
MAX_RECORD_BYTES = 256 << 20
"""Largest record the reader accepts; a larger length field is corruption (a frame chunk is ~0.1 MB)."""

StopReason = Literal["end", "truncated", "corrupt"]
CHUNK_HEADER_BYTES = 8 + 8 + 8 + 4 + 4  # start time, end time, uncompressed size, CRC, compression length
CHUNK_COMPRESSION_AT = 9 + CHUNK_HEADER_BYTES - 4
"""Offset of a chunk record's compression field from the record's start (opcode and length come first)."""
ZSTD_FIELD = struct.pack("<I", 4) + b"zstd"
"""A chunk record's compression field as tofd writes it (what resync searches for)."""
_DATA_OPCODES = frozenset({Opcode.HEADER, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.SCHEMA, Opcode.CHANNEL,
                           Opcode.CHUNK, Opcode.MESSAGE_INDEX})
"""Top-level records a tofd recording has before its end-of-data record (anything else there is damage)."""
V1_ROLE = "frame.v1"
"""Role of a format-1 channel: each of its messages is a whole frame."""
V1_TOPIC = "/camera/frame"


def channel_role(channel: Channel) -> str | None:
    """What the messages of `channel` are in a frame (V1_ROLE or format.channel_role's roles), or None."""
    if channel.topic == V1_TOPIC and channel.message_encoding == format_v1.FRAME_ENCODING:
        return V1_ROLE
    return fmt.channel_role(channel.topic, channel.message_encoding)


def frames_of(messages: list[tuple[str, bytes]]) -> list[Frame]:
    """The frames that (role, message data) pairs of one chunk, in file order, make: a format-1 frame message
    each, or a format-2 header followed by its range and amplitude images (FormatError for any other mix)."""
    frames: list[Frame] = []
    parts: dict[str, bytes] = {}
    for role, data in messages:
        if role == V1_ROLE:
            frames.append(format_v1.decode_frame(data))
        elif role == "header":
            if parts:
                raise fmt.FormatError("frame header without its images")
            parts = {role: data}
        elif role in ("range_m", "amplitude"):
            if "header" not in parts or role in parts:
                raise fmt.FormatError(f"{role} image without its frame header")
            parts[role] = data
            if len(parts) == 3:
                frames.append(fmt.decode_frame(parts["header"], parts["range_m"], parts["amplitude"]))
                parts = {}
    if parts:
        raise fmt.FormatError("frame header without its images")
    return frames


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


@dataclass(frozen=True, slots=True)
class Damage:
    """A damaged stretch of a recording that the reader skipped: bytes [start, end) and what was wrong."""

    start: int
    end: int
    detail: str


class _Bad(Exception):
    """A record that cannot be read: reason ("truncated" or "corrupt") and detail."""

    def __init__(self, reason: StopReason, detail: str) -> None:
        super().__init__(detail)
        self.reason, self.detail = reason, detail


class RecordingReader:
    """Sequential reader of one pass over a recording's records.

    Iterating `frames()` yields the decoded frames in file order and, where the file is damaged, a Damage
    before the frames read after it: the reader resyncs at the next intact chunk (found by its
    compression field and checked by its CRC), so every readable frame is read. Metadata and attachments
    seen on the way are collected in `metadata` and `attachments`. When iteration ends, `reason`/`detail`
    say why: "end" (the writer finished), "truncated" (file ends early: killed writer or cut file) or
    "corrupt" (a CRC mismatch or an unparsable record with no intact chunk after it).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                magic = f.read(len(MCAP0_MAGIC))
                self._data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if magic == MCAP0_MAGIC else None
        except OSError as exc:
            raise DriverError(f"cannot open recording {self.path}: {exc.strerror}") from None
        if self._data is None:
            raise DriverError(f"{self.path} is not a tofd recording (no MCAP magic at its start)")
        self.file_size = len(self._data)
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.damage: list[Damage] = []
        self.reason: StopReason | None = None
        self.detail = ""
        self.offset = len(MCAP0_MAGIC)  # end of the last good record, bytes
        self._roles: dict[int, str | None] = {}  # channel id -> role in a frame (None: not part of frames)
        self._previous_opcode: int | None = None
        self._chunk_seen = False
        self._unindexed: set[int] = set()  # channels of the last chunk whose message index has not been read

    def close(self) -> None:
        self._data.close()

    def __enter__(self) -> RecordingReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _record(self, offset: int) -> tuple[int, bytes]:
        """The record (opcode, body) at `offset`; _Bad if it is cut short or claims an absurd length."""
        head = self._data[offset:offset + 9]
        if len(head) < 9:
            where = "at a record boundary" if not head else "inside a record header"
            raise _Bad("truncated", f"file ends {where} at byte {offset + len(head)} without MCAP's "
                                    "end-of-data record (the writer did not finish: killed, crashed or cut)")
        opcode, length = struct.unpack("<BQ", head)
        if length > MAX_RECORD_BYTES:
            raise _Bad("corrupt", f"record at byte {offset} claims {length} bytes (opcode {opcode:#04x})")
        if offset + 9 + length > self.file_size:
            raise _Bad("truncated", f"file ends at byte {self.file_size} inside a record that starts at byte "
                                    f"{offset} and needs {length} bytes")
        return opcode, self._data[offset + 9:offset + 9 + length]

    @staticmethod
    def _chunk(body: bytes) -> Chunk:
        chunk = Chunk.read(ReadDataStream(BytesIO(body)))
        if CHUNK_HEADER_BYTES + len(chunk.compression) + 8 + len(chunk.data) != len(body):
            raise fmt.FormatError(f"chunk record of {len(body)} bytes holds {len(chunk.data)} bytes of records")
        if chunk.uncompressed_crc == 0:
            raise fmt.FormatError("chunk has no CRC (0): tofd always writes one")
        return chunk

    def _parse(self, opcode: int, body: bytes) -> list[Frame]:
        """Frames of one top-level record (raises on corruption)."""
        stream = ReadDataStream(BytesIO(body))
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL) and self._chunk_seen:
            raise fmt.FormatError("a schema or channel record after the first chunk (tofd writes them before it)")
        if opcode == Opcode.CHUNK:
            self._chunk_seen = True
            messages = []
            self._unindexed = set()
            for rec in breakup_chunk(self._chunk(body), validate_crc=True):
                if isinstance(rec, Channel):
                    self._roles[rec.id] = channel_role(rec)
                elif isinstance(rec, Message):
                    self._unindexed.add(rec.channel_id)
                    if (role := self._role(rec.channel_id)) is not None:
                        messages.append((role, rec.data))
            return frames_of(messages)
        if opcode == Opcode.CHANNEL:
            channel = Channel.read(stream)
            expected = next((c for c in fmt.CHANNELS if c.id == channel.id), None)
            if expected is not None and (channel.topic, channel.message_encoding) != (expected.topic,
                                                                                     fmt.MESSAGE_ENCODING):
                raise fmt.FormatError(f"channel record {channel.id} ({channel.topic!r}) is not tofd's channel "
                                      f"{expected.topic!r}: damaged")
            self._roles[channel.id] = channel_role(channel)
        elif opcode == Opcode.SCHEMA:
            Schema.read(stream)
        elif opcode == Opcode.METADATA:
            meta = Metadata.read(stream)
            self.metadata[meta.name] = fmt.check_metadata(meta.name, meta.metadata)
        elif opcode == Opcode.ATTACHMENT:
            crc = struct.unpack("<I", body[-4:])[0]
            if crc == 0 or zlib.crc32(body[:-4]) != crc:
                raise fmt.FormatError("attachment CRC missing (0) or mismatched")
            att = Attachment.read(stream)
            self.attachments[att.name] = att.data
        elif opcode not in _DATA_OPCODES:
            raise fmt.FormatError(f"record opcode {opcode:#04x} does not belong in a recording's data section")
        elif opcode == Opcode.MESSAGE_INDEX:
            self._check_message_index(body)
        elif opcode == Opcode.HEADER and self.offset != len(MCAP0_MAGIC):
            raise fmt.FormatError("a second header record")
        return []

    def _check_message_index(self, body: bytes) -> None:
        """A message index record must be well formed and index a channel of the chunk just before it."""
        if self._previous_opcode not in (Opcode.CHUNK, Opcode.MESSAGE_INDEX):
            raise fmt.FormatError("message index without its chunk before it (a damaged chunk record?)")
        channel_id, length = struct.unpack_from("<HI", body) if len(body) >= 6 else (None, None)
        if length is None or length % 16 or 6 + length != len(body) or channel_id not in self._unindexed:
            raise fmt.FormatError("malformed message index, or one for a channel its chunk does not hold")
        self._unindexed.discard(channel_id)

    def _role(self, channel_id: int) -> str | None:
        """Role of a message's channel; after damage, a channel whose record was lost has the role that tofd's
        writer gives its id (format 2: fmt.ROLE_BY_ID; format 1: one frame channel)."""
        if channel_id in self._roles:
            return self._roles[channel_id]
        if not self.damage:
            return None
        version = self.metadata.get(fmt.META_RECORDING, {}).get("format_version", str(fmt.FORMAT_VERSION))
        return V1_ROLE if version == "1" else fmt.ROLE_BY_ID.get(channel_id)

    def _intact_chunk(self, offset: int) -> bool:
        """Whether an intact chunk record (lengths, CRC and compression) starts at `offset`."""
        try:
            opcode, body = self._record(offset)
            if opcode != Opcode.CHUNK:
                return False
            chunk = self._chunk(body)
            records = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=chunk.uncompressed_size)
        except Exception:  # noqa: BLE001 (anything unreadable is not a resync point)
            return False
        return len(records) == chunk.uncompressed_size and zlib.crc32(records) == chunk.uncompressed_crc

    def _resync(self, after: int) -> int | None:
        """Offset of the first intact chunk record that starts after byte `after`, or None."""
        pos = after + 1 + CHUNK_COMPRESSION_AT
        while (hit := self._data.find(ZSTD_FIELD, pos)) >= 0:
            if self._intact_chunk(hit - CHUNK_COMPRESSION_AT):
                return hit - CHUNK_COMPRESSION_AT
            pos = hit + 1
        return None

    def frames(self) -> Iterator[Frame | Damage]:
        """Frames in file order, a Damage before the frames read after each damaged stretch, until the end of
        data, the end of the file or damage with no intact chunk after it."""
        while self.reason is None:
            try:
                opcode, body = self._record(self.offset)
                if opcode == Opcode.DATA_END and len(body) == 4:
                    self.reason, self.detail = "end", f"end of data at byte {self.offset} of {self.file_size}"
                    return
                try:
                    frames = self._parse(opcode, body)
                except Exception as exc:  # noqa: BLE001 (any failure to parse these bytes is corruption)
                    raise _Bad("corrupt", f"bad record at byte {self.offset} (opcode {opcode:#04x}): "
                                          f"{type(exc).__name__}: {exc}") from None
            except _Bad as bad:
                resume = self._resync(self.offset)
                if resume is None:
                    self.reason, self.detail = bad.reason, bad.detail
                    return
                damage = Damage(self.offset, resume, bad.detail)
                self.damage.append(damage)
                self.offset, self._previous_opcode = resume, None
                yield damage
                continue
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
    if summary is None or summary.statistics is None:
        return None
    frames = {c.id for c in summary.channels.values() if channel_role(c) in ("header", V1_ROLE)}
    return sum(n for channel, n in summary.statistics.channel_message_counts.items() if channel in frames)


def read_recording_info(path: str | Path) -> RecordingInfo:
    """The header of a recording: software version, intrinsics, device, registers, config, frame count.

    Raises DriverError if the file is not a tofd recording, its header records are damaged (a metadata CRC
    fails, or a record before the first frame is unreadable) or its intrinsics metadata disagrees with the
    first frame's (which its chunk CRC protects): replay configures the pipeline from this header.
    """
    with RecordingReader(path) as reader:
        first = next((item for item in reader.frames() if isinstance(item, Frame)), None)  # after the header
        header = (fmt.META_RECORDING, fmt.META_INTRINSICS, fmt.META_DEVICE, fmt.META_REGISTERS)
        if reader.damage and not all(name in reader.metadata for name in header):
            raise DriverError(f"{reader.path}: damaged recording header: {reader.damage[0].detail}")
        try:
            info = _info_from(reader, _frame_count(reader.path))
        except (ValueError, TypeError, KeyError) as exc:  # FormatError and JSON errors are ValueErrors
            raise DriverError(f"{reader.path}: damaged recording header: {exc}") from None
    if first is not None and info.intrinsics is not None and info.intrinsics != first.intrinsics:
        raise DriverError(f"{reader.path}: damaged recording header: intrinsics metadata {info.intrinsics} "
                          f"disagrees with the first frame's {first.intrinsics}")
    return info


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
    unless looping. A damaged file replays every intact frame and rejects the lost ones by counter
    ("damaged: ..."); frames that do not fit the recording ("invalid_frame: ...") or repeat an earlier one
    ("duplicate: ...") are rejected, not replayed. When the file ends early or no intact chunk follows the
    damage, `stopped_reason` ("end", "truncated" or "corrupt"), `stop_detail`, `last_good_counter` say where
    it stopped, a warning is logged and counters["corrupt_tail"] is 1.
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
        try:
            header = read_recording_info(self.path).intrinsics
        except DriverError:  # a damaged header: the frames are still checked against the default shape
            header = None
        self.shape = (header or Intrinsics()).shape
        """(H, W) every replayed frame has (the recording's intrinsics)."""
        self.mode, self.speed, self.loop = mode, float(speed), loop
        self.seek, self.start, self.stop = seek, start, stop
        self.stopped_reason: StopReason | None = None
        self.stop_detail = ""
        self.last_good_counter: int | None = None  # counter of the last frame read intact from the file
        self.frames_read = 0  # intact frames read from the file in the first pass

    def _in_range(self, counter: int) -> bool:
        return (self.start is None or counter >= self.start) and (self.stop is None or counter < self.stop)

    def _pass(self, seek: int | None, first: bool) -> Iterator[Frame]:
        """Valid frames of one pass over the file, within the range, from the first counter >= seek; invalid,
        duplicated and (by counter) lost frames are rejected (FrameSource.reject) in their place."""
        seeking, seen, damage, last = seek is not None, set(), None, None
        with RecordingReader(self.path) as reader:
            for item in reader.frames():
                if self.closed:
                    return
                if isinstance(item, Damage):
                    damage = item
                    log.warning("%s: damaged bytes %d-%d skipped: %s", self.path, item.start, item.end, item.detail)
                    continue
                problem = frame_problem(item, self.shape)
                counter, key = item.frame_counter, (item.frame_counter, item.timestamp_us)
                if problem is None and damage is not None:
                    self._reject_lost(last, counter, damage, seek if seeking else None)
                    damage = None
                if problem is None and key in seen:
                    problem = f"duplicate: frame {counter} at {item.timestamp_us} us was already replayed"
                elif problem is None:
                    seen.add(key)
                    last = counter
                    if first:
                        self.frames_read += 1
                        self.last_good_counter = counter
                else:
                    problem = f"invalid_frame: {problem}"
                if seeking and (problem is not None or counter < seek):
                    continue
                seeking = False
                if not self._in_range(counter):
                    continue
                if problem is None:
                    yield item
                else:
                    self.reject(counter, problem)
            if first:
                self._report(reader)

    def _reject_lost(self, last: int | None, counter: int, damage: Damage, seek: int | None) -> None:
        """Reject the frames between counter `last` and `counter` that `damage` destroyed."""
        if last is None or not 0 < counter - last - 1 <= MAX_LOST_FRAMES:
            log.warning("%s: frames lost to the damage at byte %d cannot be counted (counters %s -> %d)",
                        self.path, damage.start, last, counter)
            self.counters["damaged_uncounted"] += 1
            return
        for lost in range(last + 1, counter):
            if (seek is None or lost >= seek) and self._in_range(lost):
                self.reject(lost, f"damaged: bytes {damage.start}-{damage.end}: {damage.detail}")

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
