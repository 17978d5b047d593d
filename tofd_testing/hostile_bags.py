"""Hostile bags for tests/test_bounded_inputs.py: a ROS 1 bag whose last chunk is a compression bomb, a ROS 2
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
