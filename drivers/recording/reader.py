"""Reading tofd recordings: RecordingReader (one pass over a file's records, with resync) and its header,
RecordingInfo (read_recording_info / recording_info).

Reading is sequential and needs neither MCAP's summary nor its footer, so a recording whose writer was
killed replays up to its last complete frame. Every chunk's CRC is checked (a chunk without one is
refused); at a record that is cut short, fails its CRC or does not parse, the reader resyncs at the next
intact chunk, so every readable frame is replayed. Frames lost to damage (by counter), invalid frames
(tofd.drivers.frame.frame_problem) and duplicated frames (same counter and device timestamp) are rejected
by the replay (tofd.drivers.recording.replay). Every size the file declares is bounded before it is trusted
(tofd.drivers.recording.bounds): records, decompressed chunks (only zstd, which tofd writes; at most what one frame
of the recording's intrinsics needs), records per chunk, metadata, attachments, the summary and image sizes.
"""

from __future__ import annotations

import json
import mmap
import struct
import zlib
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Message, Metadata, Schema, Statistics
from mcap.writer import MCAP0_MAGIC

from tofd.drivers.frame import DeviceInfo, Frame, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.limits import image_size_problem
from tofd.drivers.recording import bounds, format_v1
from tofd.drivers.recording import format as fmt
from tofd.drivers.recording.bounds import MAX_RECORD_BYTES
from tofd.drivers.source import DriverError, StopReason

CHUNK_HEADER_BYTES = 8 + 8 + 8 + 4 + 4  # start time, end time, uncompressed size, CRC, compression length
CHUNK_COMPRESSION_AT = 9 + CHUNK_HEADER_BYTES - 4
"""Offset of a chunk record's compression field from the record's start (opcode and length come first)."""
CHUNK_COMPRESSION = "zstd"
"""The only chunk compression tofd writes (and so the only one it reads in its own recordings)."""
ZSTD_FIELD = struct.pack("<I", 4) + CHUNK_COMPRESSION.encode()
"""A chunk record's compression field as tofd writes it (what resync searches for)."""
_CHUNK_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE})
"""Records a chunk may hold."""
_RECORD_LIMITS = {Opcode.METADATA: bounds.MAX_METADATA_BYTES,
                  Opcode.ATTACHMENT: bounds.MAX_ATTACHMENT_BYTES + bounds.MAX_METADATA_BYTES}
"""Largest top-level record of these kinds, bytes (others: bounds.MAX_RECORD_BYTES)."""
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4
"""A footer record: opcode, length, summary start, summary offset start, summary CRC."""
_DATA_OPCODES = frozenset({Opcode.HEADER, Opcode.METADATA, Opcode.ATTACHMENT, Opcode.SCHEMA, Opcode.CHANNEL,
                           Opcode.CHUNK, Opcode.MESSAGE_INDEX})
"""Top-level records a tofd recording has before its end-of-data record (anything else there is damage)."""
V1_ROLE = "frame.v1"
"""Role of a format-1 channel: each of its messages is a whole frame."""
V1_TOPIC = "/camera/frame"


def _whole(text: str | None) -> object:
    """A metadata value as an integer when it is one, else as it is (for the bound's message)."""
    return int(text) if text is not None and text.lstrip("-").isdigit() else text


def channel_role(channel: Channel) -> str | None:
    """What the messages of `channel` are in a frame (V1_ROLE or format.channel_role's roles), or None."""
    if channel.topic == V1_TOPIC and channel.message_encoding == format_v1.FRAME_ENCODING:
        return V1_ROLE
    return fmt.channel_role(channel.topic, channel.message_encoding)


def frames_of(messages: list[tuple[str, bytes]]) -> list[Frame]:
    """The frames that (role, message data) pairs of one chunk, in file order, make: a format-1 frame message
    each, or a format-2 header followed by its range and amplitude images (FormatError for any other mix, or
    for a frame whose intrinsics are out of tofd.drivers.limits' bounds)."""
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


class _InPlace:
    """A read-only file over a bytes-like object whose reads are views into it, not copies: mcap's ReadDataStream
    over it parses a chunk and its records where they lie (message data and chunk data are memoryviews)."""

    def __init__(self, data: bytes | memoryview) -> None:
        self._view, self._at = memoryview(data), 0

    def read(self, size: int) -> memoryview:
        view = self._view[self._at:self._at + size]
        self._at += len(view)
        return view


def chunk_records(chunk: Chunk, limit: int) -> Iterator[Channel | Message | Schema]:
    """The records of a chunk, decompressing at most `limit` bytes (FormatError for another compression than
    zstd, a larger declared size, a CRC mismatch, more than bounds.MAX_CHUNK_RECORDS records or a record a chunk
    does not hold)."""
    if chunk.compression != CHUNK_COMPRESSION:
        raise fmt.FormatError(f"chunk compression {chunk.compression or 'none'!r}: tofd writes only "
                              f"{CHUNK_COMPRESSION}")
    if chunk.uncompressed_size > limit:
        raise fmt.FormatError(f"chunk declares {chunk.uncompressed_size} bytes decompressed, more than a frame of "
                              f"this recording can need ({limit})")
    with zstandard.ZstdDecompressor().stream_reader(chunk.data) as decompressed:
        data = decompressed.read(chunk.uncompressed_size + 1)
    if len(data) != chunk.uncompressed_size or zlib.crc32(data) != chunk.uncompressed_crc:
        raise fmt.FormatError(f"chunk decompresses to {len(data)} bytes (declared {chunk.uncompressed_size}) or "
                              "fails its CRC")
    stream = ReadDataStream(_InPlace(data))  # type: ignore[arg-type]  # a file's read() is all it calls
    for _ in range(bounds.MAX_CHUNK_RECORDS):
        if stream.count >= len(data):
            return
        opcode, length = stream.read1(), stream.read8()
        if opcode not in _CHUNK_OPCODES or length > len(data) - stream.count:
            raise fmt.FormatError(f"chunk holds a record {opcode:#04x} of {length} bytes that tofd never writes")
        start = stream.count
        if opcode == Opcode.MESSAGE:
            yield Message.read(stream, length)
        else:
            yield Channel.read(stream) if opcode == Opcode.CHANNEL else Schema.read(stream)
        if stream.count != start + length:
            raise fmt.FormatError(f"chunk record {opcode:#04x} is {stream.count - start} bytes, declared {length}")
    if stream.count < len(data):
        raise fmt.FormatError(f"chunk holds more than {bounds.MAX_CHUNK_RECORDS} records")


@dataclass(frozen=True, slots=True)
class RecordingInfo:
    """What a recording says about itself (its first records; frame_count only if the file was closed)."""

    path: Path
    format_version: int
    software_version: str
    created_wall_s: float
    intrinsics: Intrinsics | None  # None when the recording holds no frame
    device: DeviceInfo | None
    registers: Registers | None  # None: no frame, or a camera without SR3000 registers (see sensor)
    config: dict | None  # the service config it was made with (attachment config.json)
    frame_count: int | None  # from MCAP's statistics; None when the writer did not finish (crash)
    sensor: SensorInfo | None = None  # a non-SR3000 camera's signal and settings (None: SR3000, or no frame)


@dataclass(frozen=True, slots=True)
class Damage:
    """A damaged stretch of a recording that the reader skipped: bytes [start, end), what was wrong, and how many
    chunk records start in it (at least 1: the record that failed; tofd writes one frame per chunk)."""

    start: int
    end: int
    detail: str
    chunks: int = 1


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
        """Map the file (DriverError if it cannot be opened or is not MCAP); `rewind` starts another pass."""
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                magic = f.read(len(MCAP0_MAGIC))
                data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if magic == MCAP0_MAGIC else None
        except OSError as exc:
            raise DriverError(f"cannot open recording {self.path}: {exc.strerror}") from None
        if data is None:
            raise DriverError(f"{self.path} is not a tofd recording (no MCAP magic at its start)")
        self._data: mmap.mmap = data
        self.file_size = len(self._data)
        self._pending: deque[Frame | Damage] = deque()  # read by read_header, not yet taken by frames()
        self.rewind()

    def rewind(self) -> None:
        """Start a new pass at the file's first record (what the last pass learnt is forgotten)."""
        self.metadata: dict[str, dict[str, str]] = {}
        self.attachments: dict[str, bytes] = {}
        self.damage: list[Damage] = []
        self.reason: StopReason | None = None
        self.detail = ""
        self.offset = len(MCAP0_MAGIC)  # end of the last good record, bytes
        self.chunk_limit = bounds.MAX_CHUNK_BYTES  # largest decompressed chunk; a frame's size once intrinsics known
        self._roles: dict[int, str | None] = {}  # channel id -> role in a frame (None: not part of frames)
        self._previous_opcode: int | None = None
        self._chunk_seen = False
        self._unindexed: set[int] = set()  # channels of the last chunk whose message index has not been read
        self._pending.clear()

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
        if length > _RECORD_LIMITS.get(opcode, MAX_RECORD_BYTES):
            raise _Bad("corrupt", f"record at byte {offset} claims {length} bytes (opcode {opcode:#04x}), more "
                                  f"than tofd writes ({_RECORD_LIMITS.get(opcode, MAX_RECORD_BYTES)})")
        if offset + 9 + length > self.file_size:
            raise _Bad("truncated", f"file ends at byte {self.file_size} inside a record that starts at byte "
                                    f"{offset} and needs {length} bytes")
        return opcode, self._data[offset + 9:offset + 9 + length]

    @staticmethod
    def _chunk(body: bytes) -> Chunk:
        chunk = Chunk.read(ReadDataStream(_InPlace(body)))  # type: ignore[arg-type]
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
            for rec in chunk_records(self._chunk(body), self.chunk_limit):
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
            if meta.name == fmt.META_INTRINSICS:
                raw = self.metadata[meta.name]  # the size bound first: Intrinsics' own check has no file context
                if (problem := image_size_problem(_whole(raw.get("width")), _whole(raw.get("height")))):
                    raise fmt.FormatError(f"metadata {meta.name!r}: {problem}")
                intrinsics = fmt.from_metadata(Intrinsics, raw)
                self.chunk_limit = bounds.frame_chunk_limit(intrinsics)  # type: ignore[arg-type]
        elif opcode == Opcode.ATTACHMENT:
            crc = struct.unpack("<I", body[-4:])[0]
            if crc == 0 or zlib.crc32(body[:-4]) != crc:
                raise fmt.FormatError("attachment CRC missing (0) or mismatched")
            att = Attachment.read(stream)
            if len(att.data) > bounds.MAX_ATTACHMENT_BYTES:
                raise fmt.FormatError(f"attachment {att.name!r} of {len(att.data)} bytes, more than tofd writes")
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
            for _ in chunk_records(self._chunk(body), self.chunk_limit):
                pass
        except Exception:  # noqa: BLE001 (anything unreadable is not a resync point)
            return False
        return True

    def _resync(self, after: int) -> int | None:
        """Offset of the first intact chunk record that starts after byte `after`, or None."""
        pos = after + 1 + CHUNK_COMPRESSION_AT
        while (hit := self._data.find(ZSTD_FIELD, pos)) >= 0:
            if self._intact_chunk(hit - CHUNK_COMPRESSION_AT):
                return hit - CHUNK_COMPRESSION_AT
            pos = hit + 1
        return None

    def _chunk_starts(self, start: int, end: int) -> int:
        """Chunk records (their opcode and tofd's compression field, intact) starting in bytes [start, end), at
        least 1."""
        found, pos = 0, start + CHUNK_COMPRESSION_AT
        while 0 <= (hit := self._data.find(ZSTD_FIELD, pos, end + CHUNK_COMPRESSION_AT)):
            found += self._data[hit - CHUNK_COMPRESSION_AT] == Opcode.CHUNK
            pos = hit + 1
        return max(found, 1)

    def frames(self) -> Iterator[Frame | Damage]:
        """Frames in file order, a Damage before the frames read after each damaged stretch, until the end of
        data, the end of the file or damage with no intact chunk after it."""
        while self._pending or self.reason is None:
            if self._pending:
                yield self._pending.popleft()
            else:
                self._pending.extend(self._step())

    def read_header(self) -> Frame | None:
        """Read up to the first frame (the header's metadata and attachments on the way) and return it, or None if
        the pass ends first; what was read stays queued for `frames()`."""
        while self.reason is None and not any(isinstance(item, Frame) for item in self._pending):
            self._pending.extend(self._step())
        return next((item for item in self._pending if isinstance(item, Frame)), None)

    def _step(self) -> list[Frame | Damage]:
        """The frames of the next record, or the Damage found there (empty at the end of the pass)."""
        if self.reason is None:
            try:
                opcode, body = self._record(self.offset)
                if opcode == Opcode.DATA_END and len(body) == 4:
                    self.reason, self.detail = "end", f"end of data at byte {self.offset} of {self.file_size}"
                    return []
                try:
                    frames = self._parse(opcode, body)
                except Exception as exc:  # noqa: BLE001 (any failure to parse these bytes is corruption)
                    raise _Bad("corrupt", f"bad record at byte {self.offset} (opcode {opcode:#04x}): "
                                          f"{type(exc).__name__}: {exc}") from None
            except _Bad as bad:
                resume = self._resync(self.offset)
                if resume is None:
                    self.reason, self.detail = bad.reason, bad.detail
                    return []
                damage = Damage(self.offset, resume, bad.detail, self._chunk_starts(self.offset, resume))
                self.damage.append(damage)
                self.offset, self._previous_opcode = resume, None
                return [damage]
            self.offset += 9 + len(body)
            self._previous_opcode = opcode
            return list(frames)
        return []

    def frame_count(self) -> int | None:
        """Frames in the recording by MCAP's summary statistics, or None without an intact summary (the writer
        did not finish) or with one larger than bounds.MAX_SUMMARY_BYTES."""
        tail = len(MCAP0_MAGIC) + _FOOTER_BYTES
        if self.file_size < 2 * len(MCAP0_MAGIC) + _FOOTER_BYTES or self._data[-len(MCAP0_MAGIC):] != MCAP0_MAGIC:
            return None
        opcode, length, start = struct.unpack_from("<BQQ", self._data, self.file_size - tail)
        end = self.file_size - tail
        if opcode != Opcode.FOOTER or length != _FOOTER_BYTES - 9 or not 0 < start < end - 9 or \
                end - start > bounds.MAX_SUMMARY_BYTES:
            return None
        channels: dict[int, Channel] = {}
        counts: dict[int, int] | None = None
        offset = start
        try:
            while offset < end:
                opcode, length = struct.unpack_from("<BQ", self._data, offset)
                if offset + 9 + length > end:
                    return None
                body = ReadDataStream(BytesIO(self._data[offset + 9:offset + 9 + length]))
                if opcode == Opcode.CHANNEL:
                    channel = Channel.read(body)
                    channels[channel.id] = channel
                elif opcode == Opcode.STATISTICS:
                    counts = Statistics.read(body).channel_message_counts
                offset += 9 + length
        except Exception:  # noqa: BLE001 (a damaged summary only means: count unknown)
            return None
        if counts is None:
            return None
        frames = {c.id for c in channels.values() if channel_role(c) in ("header", V1_ROLE)}
        return sum(n for channel, n in counts.items() if channel in frames)


def _info_from(reader: RecordingReader) -> RecordingInfo:
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
        frame_count=reader.frame_count(),
        sensor=None if (sensor := reader.metadata.get(fmt.META_SENSOR)) is None else fmt.sensor_from_metadata(sensor),
    )


def read_recording_info(path: str | Path) -> RecordingInfo:
    """The header of the recording at `path` (recording_info of a reader of it)."""
    with RecordingReader(path) as reader:
        return recording_info(reader)


def recording_info(reader: RecordingReader) -> RecordingInfo:
    """The header of a recording: software version, intrinsics, device, registers or sensor info, config, frame
    count; read with `reader` (at the start of a pass), which then goes on from its first frame.

    Raises DriverError if the file is not a tofd recording, its header records are damaged (a metadata CRC
    fails, a size is out of bounds, or a record before the first frame is unreadable) or its intrinsics metadata
    disagrees with the first frame's (which its chunk CRC protects): replay configures the pipeline from this
    header.
    """
    first = reader.read_header()
    header = (fmt.META_RECORDING, fmt.META_INTRINSICS, fmt.META_DEVICE)
    camera = (fmt.META_REGISTERS, fmt.META_SENSOR)  # an SR3000's registers or another camera's sensor info
    if (reader.damage or reader.reason == "corrupt") and not (
            all(name in reader.metadata for name in header) and any(name in reader.metadata for name in camera)):
        detail = reader.damage[0].detail if reader.damage else reader.detail
        raise DriverError(f"{reader.path}: damaged recording header: {detail}")
    try:
        info = _info_from(reader)
    except (ValueError, TypeError, KeyError, RecursionError) as exc:  # FormatError and JSON errors: ValueErrors
        raise DriverError(f"{reader.path}: damaged recording header: {exc}") from None
    if first is not None and info.intrinsics is not None and info.intrinsics != first.intrinsics:
        raise DriverError(f"{reader.path}: damaged recording header: intrinsics metadata {info.intrinsics} "
                          f"disagrees with the first frame's {first.intrinsics}")
    return info


