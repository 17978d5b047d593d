"""Hostile bags for tests/drivers/test_bounded_inputs.py: a ROS 1 bag whose last chunk is a compression bomb, a ROS 2
sqlite3 bag cut short whose header claims gigabytes of pages, and PNG headers that declare huge images.

Each maker edits a bag that rosbags' own writer wrote, so everything but the hostile part is intact.
"""

from __future__ import annotations

import bz2
import struct
import zlib
from pathlib import Path

import lz4.frame

_PIECE = bytes(1 << 20)


def _fields(data: bytes, pos: int) -> tuple[dict[str, bytes], int]:
    """(fields, end) of the ROS 1 record header at `pos` (its 4-byte length first)."""
    (length,) = struct.unpack_from("<I", data, pos)
    fields, at = {}, pos + 4
    while at < pos + 4 + length:
        (size,) = struct.unpack_from("<I", data, at)
        name, _, value = data[at + 4:at + 4 + size].partition(b"=")
        fields[name.decode()] = value
        at += 4 + size
    return fields, at


def _compressed(compression: str, records: bytes, zeros: int) -> bytes:
    """`records` then `zeros` zero bytes, compressed as one bz2 or LZ4-frame stream (streamed)."""
    compressor = bz2.BZ2Compressor() if compression == "bz2" else lz4.frame.LZ4FrameCompressor()
    parts = [] if compression == "bz2" else [compressor.begin()]
    parts.append(compressor.compress(records))
    for _ in range(zeros // len(_PIECE)):
        parts.append(compressor.compress(_PIECE))
    parts.append(compressor.flush())
    return b"".join(parts)


def ros1_chunk_bomb(bag: Path, out: Path, zeros: int) -> Path:
    """`out`: the compressed ROS 1 `bag` whose last chunk decompresses to its records and then `zeros` zero
    bytes (its header still declares the old size; the file header's index position follows the longer chunk)."""
    from rosbags.rosbag1 import Reader

    with Reader(bag) as reader:
        pos = reader.chunk_infos[-1].pos
    data = bag.read_bytes()
    fields, body_at = _fields(data, pos)
    compression = fields["compression"].decode()
    (length,) = struct.unpack_from("<I", data, body_at)
    body = data[body_at + 4:body_at + 4 + length]
    records = bz2.decompress(body) if compression == "bz2" else lz4.frame.decompress(body)
    bomb = _compressed(compression, records, zeros)
    patched = data[:body_at] + struct.pack("<I", len(bomb)) + bomb + data[body_at + 4 + length:]
    header, _ = _fields(data, 13)  # the file header record follows the 13-byte magic
    index_pos = struct.unpack("<Q", header["index_pos"])[0] + len(bomb) - length
    at = patched.index(b"index_pos=", 13) + len(b"index_pos=")
    out.write_bytes(patched[:at] + struct.pack("<Q", index_pos) + patched[at + 8:])
    return out


def sqlite_page_claim(db3: Path, out: Path, keep: float, claimed_bytes: int) -> Path:
    """`out`: the first `keep` of sqlite3 file `db3`, its header's page count raised to `claimed_bytes`."""
    data = bytearray(db3.read_bytes()[:int(db3.stat().st_size * keep)])
    page_size = struct.unpack(">H", data[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    data[28:32] = struct.pack(">I", claimed_bytes // page_size)
    out.write_bytes(bytes(data))
    return out


def png_header(width: int, height: int, bit_depth: int = 16) -> bytes:
    """A greyscale PNG's signature and IHDR declaring width x height, then one IDAT of a few zero rows and IEND:
    a decoder that trusts the header allocates width * height pixels."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    rows = zlib.compress(bytes((1 + width * bit_depth // 8) * 4))
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


def mcap_chunk_bomb(bag: Path, out: Path, zeros: int) -> Path:
    """`out`: the messages of the ROS 2 MCAP bag file `bag` rewritten in zstd chunks of about 1 KiB, then a
    message of `zeros` zero bytes on a topic of its own (one chunk that decompresses to it)."""
    from mcap.reader import NonSeekingReader
    from mcap.writer import CompressionType, Writer

    with open(bag, "rb") as src, open(out, "wb") as dst:
        writer = Writer(dst, chunk_size=1 << 10, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="tofd_testing")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        last = 0
        for schema, channel, message in NonSeekingReader(src).iter_messages(log_time_order=False):
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], channel.metadata)
            writer.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
            last = message.log_time
        junk = writer.register_channel("/junk", "cdr", next(iter(schemas.values())))
        writer.add_message(junk, last + 1, bytes(zeros), last + 1)
        writer.finish()
    return out
