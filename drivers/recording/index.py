"""Random access to a finished recording's frames through MCAP's chunk index (its summary section).

A tofd recording holds one frame per chunk (format 2: its header, images and calibration messages), so chunk k
(in file order) is frame k: reading frames [first, stop) seeks straight to chunk `first` and never scans the
chunks before it. Works on any seekable binary file object (a local file or an fsspec file). A recording
without an intact summary (its writer was killed) has no index: read it sequentially with
tofd.drivers.recording.reader.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from io import BytesIO
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Message

from tofd.drivers.frame import Frame
from tofd.drivers.recording.bounds import MAX_CHUNK_BYTES, MAX_RECORD_BYTES
from tofd.drivers.recording.reader import channel_role, chunk_records, frames_of

_FOOTER_TAIL = 8 + 8 + 4 + 8
"""Bytes from the footer record's summary_start field to the end of an MCAP file."""


@dataclass(frozen=True, slots=True)
class FrameIndex:
    """Where each chunk of a recording starts (bytes, file order) and the (channel id, role) of each channel whose
    messages make frames (roles: tofd.drivers.recording.reader.channel_role)."""

    chunk_offsets: tuple[int, ...]
    frame_channels: frozenset[tuple[int, str]]
    digest: str  # sha256 of the file's summary section: changes when the recording does

    @property
    def chunk_count(self) -> int:
        return len(self.chunk_offsets)


@dataclass(frozen=True, slots=True)
class ChunkFrames:
    """The frames of one chunk, or why the chunk could not be read (error: one line)."""

    ordinal: int
    frames: list[Frame]
    error: str = ""


def frame_index(f: IO[bytes]) -> FrameIndex | None:
    """The index of the recording open in `f`, or None if it has no intact summary (writer did not finish)."""
    try:
        f.seek(0)
        reader = make_reader(f)
        summary = reader.get_summary()
    except Exception:  # noqa: BLE001 (a missing or damaged summary only means: no index)
        return None
    if summary is None or not summary.chunk_indexes:
        return None
    offsets = tuple(sorted(ci.chunk_start_offset for ci in summary.chunk_indexes))
    channels = frozenset((c.id, role) for c in summary.channels.values() if (role := channel_role(c)) is not None)
    f.seek(-_FOOTER_TAIL, 2)  # the footer's summary_start field, then summary_offset_start, summary_crc, magic
    f.seek(struct.unpack("<Q", f.read(8))[0])
    digest = hashlib.sha256(f.read()).hexdigest()
    return FrameIndex(offsets, channels, digest)


def _read_chunk(f: IO[bytes], offset: int, channels: frozenset[tuple[int, str]]) -> list[Frame]:
    """Frames of the chunk record at byte `offset` (CRC-checked; raises on damage)."""
    f.seek(offset)
    head = f.read(9)
    if len(head) < 9:
        raise ValueError(f"file ends inside the record header at byte {offset}")
    opcode, length = struct.unpack("<BQ", head)
    if opcode != Opcode.CHUNK or length > MAX_RECORD_BYTES:
        raise ValueError(f"no chunk record at byte {offset} (opcode {opcode:#04x}, {length} bytes)")
    body = f.read(length)
    if len(body) < length:
        raise ValueError(f"file ends inside the chunk at byte {offset}")
    chunk = Chunk.read(ReadDataStream(BytesIO(body)))
    roles = dict(channels)
    return frames_of([(roles[rec.channel_id], rec.data) for rec in chunk_records(chunk, MAX_CHUNK_BYTES)
                      if isinstance(rec, Message) and rec.channel_id in roles])


def read_chunks(f: IO[bytes], index: FrameIndex, first: int, stop: int) -> Iterator[ChunkFrames]:
    """Chunks first <= k < stop of the recording open in `f`, each with its frames; a damaged chunk yields its
    error and reading goes on with the next one."""
    for k in range(first, min(stop, index.chunk_count)):
        try:
            frames = _read_chunk(f, index.chunk_offsets[k], index.frame_channels)
        except Exception as exc:  # noqa: BLE001 (any failure to parse these bytes is damage of this chunk)
            yield ChunkFrames(k, [], f"chunk {k} at byte {index.chunk_offsets[k]}: {type(exc).__name__}: {exc}")
            continue
        yield ChunkFrames(k, frames)
