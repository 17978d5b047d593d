"""Hostile inputs for tests/commands/test_hostile.py and bench/hostile.py: recordings whose chunks, records, header
metadata or attachments claim what no camera sends, dataset .npz bombs and configs out of every bound.

Each maker writes one file into a directory and returns its path; RECORDING_CASES / DATASET_CASES / CONFIG_CASES
name them with the limit that must hold (drivers/recording/bounds.py, tofd/config.py, tofd/lab/npz.py).
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Attachment, Chunk, Message, Metadata

from tofd.drivers.recording import format as fmt
from tofd.drivers.recording.bounds import MAX_ATTACHMENT_BYTES, MAX_CHUNK_BYTES
from tofd.drivers.recording.mcap_writer import McapChunkWriter
from tofd.lab.npz import MAX_LOADED_BYTES
from tofd_testing.recording_helpers import frame_spans, write_recording

BASE_FRAMES = 4  # frames of the intact recording each chunk case is spliced into (after its second frame)
BOMB_BYTES = 1 << 30  # what a recording's decompression bomb decompresses to
NPZ_BOMB_BYTES = MAX_LOADED_BYTES + (256 << 20)  # what a dataset bomb decompresses to (deflate: ~10 s to make)


def _record(record: object) -> bytes:
    builder = RecordBuilder()
    record.write(builder)  # type: ignore[attr-defined]
    return builder.end()


def _spliced(work: Path, name: str, inserted: bytes) -> Path:
    """A closed BASE_FRAMES-frame recording with `inserted` (whole records) after its second frame's records."""
    base = work / f"{name}.base.mcap"
    write_recording(base, range(BASE_FRAMES))
    _, _, end = frame_spans(base)[1]
    data = base.read_bytes()
    base.unlink()
    path = work / f"{name}.mcap"
    path.write_bytes(data[:end] + inserted + data[end:])
    return path


def _chunk(records: bytes, compression: str, data: bytes | None = None, size: int | None = None) -> bytes:
    return _record(Chunk(message_start_time=0, message_end_time=0, uncompressed_size=len(records) if size is None
                         else size, uncompressed_crc=zlib.crc32(records), compression=compression,
                         data=records if data is None else data))


def _zeros_zstd(n: int) -> bytes:
    """zstd of n zero bytes, streamed (never n bytes in memory)."""
    out = zstandard.ZstdCompressor(level=1).compressobj(size=n)
    block, parts, left = bytes(1 << 20), [], n
    while left:
        parts.append(out.compress(block[:min(left, len(block))]))
        left -= min(left, len(block))
    parts.append(out.flush())
    return b"".join(parts)


def _zeros_chunk(n: int) -> bytes:
    """A zstd chunk record of n zero bytes with their right CRC."""
    crc, block = 0, bytes(1 << 20)
    for at in range(0, n, len(block)):
        crc = zlib.crc32(block[:min(len(block), n - at)], crc)
    return _record(Chunk(message_start_time=0, message_end_time=0, uncompressed_size=n, uncompressed_crc=crc,
                         compression="zstd", data=_zeros_zstd(n)))


def zstd_bomb(work: Path) -> Path:
    """A chunk of 1 GiB of zeros, ~40 KB on disk."""
    return _spliced(work, "zstd_bomb", _zeros_chunk(BOMB_BYTES))


def chunk_flood(work: Path, count: int = 300) -> Path:
    """`count` chunks of just under the global cap of zeros each (a few GB in all; more than a frame needs)."""
    return _spliced(work, "chunk_flood", _zeros_chunk(MAX_CHUNK_BYTES - 1) * count)


def lz4_chunk(work: Path) -> Path:
    """A chunk in lz4 (tofd writes only zstd)."""
    message = _record(Message(channel_id=1, sequence=0, log_time=0, publish_time=0, data=b"x" * 100))
    return _spliced(work, "lz4_chunk", _chunk(message, "lz4", b"\x04\x22\x4d\x18" + bytes(50)))


def uncompressed_chunk(work: Path) -> Path:
    """A chunk stored without compression (tofd never writes one)."""
    message = _record(Message(channel_id=1, sequence=0, log_time=0, publish_time=0, data=b"x" * 100))
    return _spliced(work, "uncompressed_chunk", _chunk(message, ""))


def record_flood(work: Path) -> Path:
    """A chunk of 10,000 empty message records (tofd writes four per chunk)."""
    message = _record(Message(channel_id=9, sequence=0, log_time=0, publish_time=0, data=b""))
    records = message * 10_000
    return _spliced(work, "record_flood", _chunk(records, "zstd", zstandard.compress(records)))


def absurd_record_length(work: Path) -> Path:
    """A record header claiming 2**40 bytes."""
    return _spliced(work, "absurd_record_length", struct.pack("<BQ", 0x06, 1 << 40) + bytes(64))


def _header_only(work: Path, name: str, intrinsics: dict[str, str], attachment: bytes | None = None) -> Path:
    """A closed recording with no frames whose header holds `intrinsics` (sealed) and `attachment` as config.json."""
    path = work / f"{name}.mcap"
    with open(path, "wb") as f:
        writer = McapChunkWriter(f, profile=fmt.PROFILE, library="hostile")
        writer.add_metadata(fmt.META_RECORDING, fmt.seal_metadata({"format_version": str(fmt.FORMAT_VERSION),
                                                                  "software_version": "0", "created_wall_s": "0.0"}))
        if attachment is not None:
            writer.add_attachment(0, fmt.CONFIG_ATTACHMENT, "application/json", attachment)
        writer.add_metadata(fmt.META_INTRINSICS, fmt.seal_metadata(intrinsics))
        writer.finish()
    return path


def _intrinsics(**changes: str) -> dict[str, str]:
    return {"width": "176", "height": "144", "fx": "200.0", "fy": "200.0", "cx": "87.5", "cy": "71.5", **changes}


def header_4000x4000(work: Path) -> Path:
    return _header_only(work, "header_4000x4000", _intrinsics(width="4000", height="4000"))


def header_100000x100000(work: Path) -> Path:
    return _header_only(work, "header_100000x100000", _intrinsics(width="100000", height="100000"))


def header_width_0(work: Path) -> Path:
    return _header_only(work, "header_width_0", _intrinsics(width="0"))


def header_fx_nan(work: Path) -> Path:
    return _header_only(work, "header_fx_nan", _intrinsics(fx="nan"))


def header_fx_tiny(work: Path) -> Path:
    return _header_only(work, "header_fx_tiny", _intrinsics(fx="1e-300"))


def header_cx_huge(work: Path) -> Path:
    return _header_only(work, "header_cx_huge", _intrinsics(cx="1e300"))


def attachment_50mb(work: Path) -> Path:
    return _header_only(work, "attachment_50mb", _intrinsics(), b"{" + b" " * (50 << 20) + b"}")


def deep_json_config(work: Path) -> Path:
    depth = MAX_ATTACHMENT_BYTES // 2 - 1
    return _header_only(work, "deep_json_config", _intrinsics(), b"[" * depth + b"]" * depth)


def metadata_flood(work: Path) -> Path:
    """A metadata record of 30 MB (tofd's are a few hundred bytes)."""
    record = _record(Metadata(name="x", metadata={"k": "v" * (30 << 20)}))
    return _spliced(work, "metadata_flood", record)


def attachment_flood(work: Path) -> Path:
    """An attachment record of 30 MB after the frames started."""
    record = _record(Attachment(create_time=0, log_time=0, name="x", media_type="x", data=bytes(30 << 20)))
    return _spliced(work, "attachment_flood", record)


RECORDING_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "zstd_bomb": (zstd_bomb, "chunk <= a frame's size decompressed"),
    "chunk_flood": (chunk_flood, "chunk <= a frame's size decompressed"),
    "lz4_chunk": (lz4_chunk, "chunks only zstd"),
    "uncompressed_chunk": (uncompressed_chunk, "chunks only zstd"),
    "record_flood": (record_flood, "<= 64 records per chunk"),
    "absurd_record_length": (absurd_record_length, "record <= 16 MiB"),
    "metadata_flood": (metadata_flood, "metadata record <= 64 KiB"),
    "attachment_flood": (attachment_flood, "attachment <= 1 MiB"),
    "header_4000x4000": (header_4000x4000, "image <= 2 Mpx"),
    "header_100000x100000": (header_100000x100000, "image <= 4096 a side"),
    "header_width_0": (header_width_0, "image size > 0"),
    "header_fx_nan": (header_fx_nan, "focal length finite > 0"),
    "header_fx_tiny": (header_fx_tiny, "focal length within 0.01..1000 image sides"),
    "header_cx_huge": (header_cx_huge, "principal point near the image"),
    "attachment_50mb": (attachment_50mb, "attachment <= 1 MiB"),
    "deep_json_config": (deep_json_config, "JSON nesting"),
}
"""Hostile recordings: maker and the limit that must hold. The frames of the chunk cases replay (the inserted
chunk is ledgered as damage); the header cases are refused with one line, exit 2."""


# ---------------------------------------------------------------- datasets

def _npz_member(zf: zipfile.ZipFile, name: str, header: bytes, body_bytes: int) -> None:
    """A .npy member: `header` then `body_bytes` zeros, deflated (streamed)."""
    with zf.open(name + ".npy", "w", force_zip64=True) as out:
        out.write(header)
        block, left = bytes(1 << 20), body_bytes
        while left:
            out.write(block[:min(left, len(block))])
            left -= min(left, len(block))


def _npy_header(shape: tuple[int, ...], dtype: str = "<f4") -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buffer.getvalue()


def npz_bomb(work: Path, size: int = NPZ_BOMB_BYTES) -> Path:
    """A dataset .npz whose range stack decompresses to `size` bytes (about a thousandth of that on disk)."""
    path = work / "npz_bomb.npz"
    frames = size // (144 * 176 * 4)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        _npz_member(zf, "range", _npy_header((frames, 144, 176)), frames * 144 * 176 * 4)
    return path


def npz_lying_header(work: Path) -> Path:
    """A dataset .npz whose range header declares 10**12 frames over a few bytes."""
    path = work / "npz_lying_header.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        _npz_member(zf, "range", _npy_header((10**12, 144, 176)), 64)
    return path


DATASET_CASES: dict[str, tuple[Callable[[Path], Path], str]] = {
    "npz_bomb": (npz_bomb, "dataset member <= its cap decompressed"),
    "npz_lying_header": (npz_lying_header, "member size = its header's shape"),
}


# ---------------------------------------------------------------- configs

CONFIG_CASES: dict[str, tuple[str, str]] = {
    "shutdown_timeout_inf": ("[pipeline]\nshutdown_timeout_s = inf\n", "pipeline.shutdown_timeout_s"),
    "input_queue_1e9": ("[pipeline]\ninput_queue = 1000000000\n", "pipeline.input_queue"),
    "workers_1000": ("[pipeline]\nworkers = 1000\n", "pipeline.workers"),
    "read_timeout_inf": ("[camera]\nread_timeout_s = inf\n", "camera.read_timeout_s"),
    "tasks_per_worker_1e9": ("[pipeline]\ntasks_per_worker = 1000000000\n", "pipeline.tasks_per_worker"),
    "fx_nan": ("[intrinsics]\nfx = nan\n", "intrinsics.fx"),
    "model_dev_zero": ('[detector]\nmodel_path = "/dev/zero"\n', "detector.model_path"),
    "model_missing": ('[detector]\nmodel_path = "absent.json"\n', "detector.model_path"),
    "toml_5000_deep": ("a = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
}
"""Hostile configs: TOML text and what the one-line config error must name."""
