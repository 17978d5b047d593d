"""Reader of format-1 frame messages (channel /camera/frame, message encoding "tofd.frame.v1"), so that
recordings made before format 2 still replay; tofd no longer writes them.

A format-1 frame message is: uint32 little-endian n, then n bytes of UTF-8 JSON (the header: counter,
timestamps, intrinsics, device, registers, ground truth, and the plane list), then the planes' bytes in list
order, each byte-shuffled (byte 0 of every value, then byte 1, ...):
  "u16_shuffled": uint16 raw values; value = float32(float64(raw) * scale), raw == invalid -> NaN.
  "f32_shuffled": float32 values.
"""

from __future__ import annotations

import json
import struct

import numpy as np

from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, Registers
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.format import FormatError, raw_to_plane

FRAME_ENCODING = "tofd.frame.v1"
_LEN = struct.Struct("<I")


def _unshuffle(blob: bytes | memoryview, dtype: str, shape: tuple[int, ...]) -> np.ndarray:
    itemsize = np.dtype(dtype).itemsize
    count = int(np.prod(shape))
    planes = np.frombuffer(blob, dtype=np.uint8, count=itemsize * count).reshape(itemsize, count)
    return planes.T.copy().view(dtype).reshape(shape)


def decode_plane(desc: dict, blob: bytes | memoryview) -> np.ndarray:
    """The float32 plane (a new, writable array) a codec description and its bytes stand for."""
    shape = tuple(desc["shape"])
    if desc["codec"] == "u16_shuffled":
        return raw_to_plane(_unshuffle(blob, "<u2", shape), float(desc["scale"]), desc["invalid"])
    if desc["codec"] == "f32_shuffled":
        return _unshuffle(blob, "<f4", shape).astype(np.float32, copy=False)
    raise FormatError(f"plane {desc.get('name')!r}: unknown codec {desc['codec']!r}")


def decode_header(data: bytes | memoryview) -> tuple[dict, int]:
    """The JSON header of a frame message and the offset of its first plane."""
    if len(data) < _LEN.size:
        raise FormatError(f"frame message of {len(data)} bytes is too short")
    (n,) = _LEN.unpack_from(data)
    end = _LEN.size + n
    if end > len(data):
        raise FormatError(f"frame header length {n} runs past the message ({len(data)} bytes)")
    try:
        header = json.loads(bytes(data[_LEN.size:end]))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"frame header is not JSON: {exc}") from None
    if not isinstance(header, dict) or "planes" not in header:
        raise FormatError("frame header lacks 'planes'")
    if sum(int(p["nbytes"]) for p in header["planes"]) != len(data) - end:
        raise FormatError("frame planes do not add up to the message length")
    return header, end


def _ground_truth(d: dict | None) -> GroundTruth | None:
    if d is None:
        return None
    xyz = d["nose_xyz_m"]
    return GroundTruth(nose_px=(float(d["nose_px"][0]), float(d["nose_px"][1])), visible=bool(d["visible"]),
                       nose_xyz_m=None if xyz is None else (float(xyz[0]), float(xyz[1]), float(xyz[2])))


def decode_frame(data: bytes | memoryview) -> Frame:
    """The Frame a format-1 frame message holds (FormatError if it does not follow the layout)."""
    header, offset = decode_header(data)
    try:
        arrays = {}
        view = memoryview(data)
        for desc in header["planes"]:
            nbytes = int(desc["nbytes"])
            arrays[desc["name"]] = decode_plane(desc, view[offset:offset + nbytes])
            offset += nbytes
        return Frame(
            range_m=arrays["range_m"],
            amplitude=arrays["amplitude"],
            frame_counter=int(header["frame_counter"]),
            timestamp_us=int(header["timestamp_us"]),
            host_monotonic_s=float(header["host_monotonic_s"]),
            host_wall_s=float(header["host_wall_s"]),
            intrinsics=Intrinsics.from_dict(header["intrinsics"]),
            device=DeviceInfo(**header["device"]),
            registers=Registers(**header["registers"]),
            ground_truth=_ground_truth(header["ground_truth"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"frame message does not decode: {type(exc).__name__}: {exc}") from None
