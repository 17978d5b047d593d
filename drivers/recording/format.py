"""Layout of a tofd recording (an MCAP file): names of its records and the codec of one frame message.

A recording is an MCAP file (https://mcap.dev) with profile "tofd":

- Metadata records at the start: "tofd.recording" (format version, software version, creation time),
  then, before the first frame, "tofd.intrinsics", "tofd.device" and "tofd.registers" (all values strings).
- An attachment "config.json" (application/json): the service configuration the recording was made with.
- One channel FRAME_TOPIC with message encoding FRAME_ENCODING (schema FRAME_SCHEMA_NAME, a JSON Schema
  of the frame header). One message per frame, each in its own zstd-compressed, CRC-32-checked chunk.
  Message log_time = host wall clock (ns), publish_time = device timestamp (ns), sequence = frame counter
  (mod 2**32); the exact values are in the message itself.

A frame message is: uint32 little-endian n, then n bytes of UTF-8 JSON (the header: counter, timestamps,
intrinsics, device, registers, ground truth, and the plane list), then the planes' bytes in list order.
Plane codecs (both lossless for what a Frame holds, checked bit for bit when encoding); the values are
stored little-endian and byte-shuffled (byte 0 of every value, then byte 1, ...), which compresses better:
  "u16_shuffled": uint16 raw values; value = float32(float64(raw) * scale), raw == invalid -> NaN.
         Used when the plane is exactly such a conversion (what the USB backend delivers).
  "f32_shuffled": float32 values. Used for any other float32 plane.
"""

from __future__ import annotations

import dataclasses
import json
import struct
import typing
import zlib

import numpy as np

from drivers.frame import DeviceInfo, Frame, GroundTruth, Registers
from drivers.intrinsics import Intrinsics
from drivers.usb import protocol as p

FORMAT_VERSION = 1
PROFILE = "tofd"
FRAME_TOPIC = "/camera/frame"
FRAME_ENCODING = "tofd.frame.v1"
FRAME_SCHEMA_NAME = "tofd.Frame"
META_RECORDING = "tofd.recording"
META_INTRINSICS = "tofd.intrinsics"
META_DEVICE = "tofd.device"
META_REGISTERS = "tofd.registers"
CONFIG_ATTACHMENT = "config.json"
METADATA_CRC_KEY = "crc32"

_LEN = struct.Struct("<I")

FRAME_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": FRAME_SCHEMA_NAME,
    "description": (
        "Header of one TOF frame. The message is uint32 LE n, n bytes of this JSON, then the planes' "
        "bytes in 'planes' order. Codec 'u16_shuffled': uint16 LE raw, value = float32(float64(raw) * scale), "
        "raw == invalid -> NaN. Codec 'f32_shuffled': float32 LE. Both byte-shuffled (byte 0 of every value, "
        "then byte 1, ...). Planes are row-major, row 0 at the top."
    ),
    "type": "object",
    "required": ["frame_counter", "timestamp_us", "host_monotonic_s", "host_wall_s", "intrinsics", "device",
                 "registers", "ground_truth", "planes"],
    "properties": {
        "frame_counter": {"type": "integer", "description": "device frame counter"},
        "timestamp_us": {"type": "integer", "description": "device clock at end of exposure, microseconds"},
        "host_monotonic_s": {"type": "number", "description": "host monotonic clock at receive, seconds"},
        "host_wall_s": {"type": "number", "description": "host wall clock (Unix time) at receive, seconds"},
        "intrinsics": {"type": "object", "description": "pinhole intrinsics in pixels (fx, fy, cx, cy, width, height)"},
        "device": {"type": "object", "description": "serial, firmware, backend, model"},
        "registers": {"type": "object", "description": "int_time_code, mod_freq_index, acq_mode, data_source, "
                                                       "amp_threshold"},
        "ground_truth": {
            "type": ["object", "null"],
            "description": "nose_px [u, v] pixels (u = column), visible, nose_xyz_m [x, y, z] metres or null",
        },
        "planes": {
            "type": "array",
            "items": {
                "type": "object",
                "required": ["name", "shape", "codec", "nbytes"],
                "properties": {
                    "name": {"enum": ["range_m", "amplitude"]},
                    "shape": {"type": "array", "items": {"type": "integer"}},
                    "codec": {"enum": ["u16_shuffled", "f32_shuffled"]},
                    "scale": {"type": "number"},
                    "invalid": {"type": ["integer", "null"]},
                    "nbytes": {"type": "integer"},
                },
            },
        },
    },
}


class FormatError(ValueError):
    """A frame message or metadata record that does not follow this layout."""


def range_scales_m(registers: Registers) -> tuple[float, ...]:
    """Candidate metres per raw distance unit at the frame's modulation frequency (raw/65535 * c/(2 f)):
    rounded to float32 as the USB backend multiplies (drivers.usb.protocol.raw_to_range_m), and exact."""
    scale = p.non_ambiguity_range_m(p.mod_freq_khz(registers.mod_freq_index)) / 65535.0
    return float(np.float32(scale)), scale


def _decode_u16(raw: np.ndarray, scale: float, invalid: int | None) -> np.ndarray:
    out = (raw.astype(np.float64) * scale).astype(np.float32)
    if invalid is not None:
        out[raw == invalid] = np.nan
    return out


def _shuffle(values: np.ndarray) -> bytes:
    return values.view(np.uint8).reshape(-1, values.itemsize).T.tobytes()


def _unshuffle(blob: bytes | memoryview, dtype: str, shape: tuple[int, ...]) -> np.ndarray:
    itemsize = np.dtype(dtype).itemsize
    count = int(np.prod(shape))
    planes = np.frombuffer(blob, dtype=np.uint8, count=itemsize * count).reshape(itemsize, count)
    return planes.T.copy().view(dtype).reshape(shape)


def encode_plane(plane: np.ndarray, scales: tuple[float, ...], invalid: int | None) -> tuple[dict, bytes]:
    """Codec description and bytes of a float32 plane: "u16_shuffled" with the first of `scales` that
    reproduces it bit for bit, else "f32_shuffled"."""
    valid = np.isfinite(plane)
    for scale in scales:
        with np.errstate(invalid="ignore", divide="ignore"):
            raw = np.where(valid, np.rint(plane / np.float64(scale)), -1.0 if invalid is None else invalid)
        if not np.all((raw >= 0) & (raw <= 0xFFFF)):
            continue
        raw16 = raw.astype("<u2")
        if np.array_equal(_decode_u16(raw16, scale, invalid).view(np.uint32), plane.view(np.uint32)):
            return {"codec": "u16_shuffled", "scale": scale, "invalid": invalid}, _shuffle(raw16)
    return {"codec": "f32_shuffled"}, _shuffle(plane.astype("<f4", copy=False))


def decode_plane(desc: dict, blob: bytes | memoryview) -> np.ndarray:
    """The float32 plane (a new, writable array) a codec description and its bytes stand for."""
    shape = tuple(desc["shape"])
    if desc["codec"] == "u16_shuffled":
        return _decode_u16(_unshuffle(blob, "<u2", shape), float(desc["scale"]), desc["invalid"])
    if desc["codec"] == "f32_shuffled":
        return _unshuffle(blob, "<f4", shape).astype(np.float32, copy=False)
    raise FormatError(f"plane {desc.get('name')!r}: unknown codec {desc['codec']!r}")


def _check_plane(name: str, plane: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    if not isinstance(plane, np.ndarray) or plane.dtype != np.float32 or plane.shape != shape:
        got = f"{getattr(plane, 'dtype', type(plane).__name__)} {getattr(plane, 'shape', '')}"
        raise ValueError(f"frame.{name}: expected float32 array of shape {shape}, got {got}")
    return np.ascontiguousarray(plane)


def ground_truth_to_json(gt: GroundTruth | None) -> dict | None:
    if gt is None:
        return None
    xyz = None if gt.nose_xyz_m is None else [float(c) for c in gt.nose_xyz_m]
    return {"nose_px": [float(c) for c in gt.nose_px], "visible": bool(gt.visible), "nose_xyz_m": xyz}


def ground_truth_from_json(d: dict | None) -> GroundTruth | None:
    if d is None:
        return None
    xyz = d["nose_xyz_m"]
    return GroundTruth(nose_px=(float(d["nose_px"][0]), float(d["nose_px"][1])), visible=bool(d["visible"]),
                       nose_xyz_m=None if xyz is None else (float(xyz[0]), float(xyz[1]), float(xyz[2])))


def encode_frame(frame: Frame) -> bytes:
    """The message bytes of one frame (see the module docstring for the layout)."""
    shape = frame.intrinsics.shape
    planes = [
        ("range_m", _check_plane("range_m", frame.range_m, shape), range_scales_m(frame.registers), p.RAW_INVALID),
        ("amplitude", _check_plane("amplitude", frame.amplitude, shape), (1.0,), None),
    ]
    descs, blobs = [], []
    for name, plane, scale, invalid in planes:
        desc, blob = encode_plane(plane, scale, invalid)
        descs.append({"name": name, "shape": list(shape), **desc, "nbytes": len(blob)})
        blobs.append(blob)
    header = {
        "frame_counter": int(frame.frame_counter),
        "timestamp_us": int(frame.timestamp_us),
        "host_monotonic_s": float(frame.host_monotonic_s),
        "host_wall_s": float(frame.host_wall_s),
        "intrinsics": frame.intrinsics.to_dict(),
        "device": dataclasses.asdict(frame.device),
        "registers": dataclasses.asdict(frame.registers),
        "ground_truth": ground_truth_to_json(frame.ground_truth),
        "planes": descs,
    }
    text = json.dumps(header, separators=(",", ":")).encode()
    return b"".join([_LEN.pack(len(text)), text, *blobs])


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


def decode_frame(data: bytes | memoryview) -> Frame:
    """The Frame a frame message holds (FormatError if it does not follow the layout)."""
    header, planes_offset = decode_header(data)
    try:
        arrays = {}
        offset = planes_offset
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
            ground_truth=ground_truth_from_json(header["ground_truth"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"frame message does not decode: {type(exc).__name__}: {exc}") from None


def _metadata_crc(data: dict[str, str]) -> str:
    return str(zlib.crc32(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()))


def seal_metadata(data: dict[str, str]) -> dict[str, str]:
    """`data` plus METADATA_CRC_KEY: CRC-32 of its canonical JSON (MCAP metadata records carry no CRC)."""
    return {**data, METADATA_CRC_KEY: _metadata_crc(data)}


def check_metadata(name: str, data: dict[str, str]) -> dict[str, str]:
    """`data` without its METADATA_CRC_KEY; FormatError if that CRC does not match (files of format
    version 1 have none: their metadata is checked against the frames instead)."""
    if METADATA_CRC_KEY not in data:
        return data
    body = {k: v for k, v in data.items() if k != METADATA_CRC_KEY}
    if _metadata_crc(body) != data[METADATA_CRC_KEY]:
        raise FormatError(f"metadata {name!r} fails its CRC")
    return body


def to_metadata(obj: object) -> dict[str, str]:
    """A dataclass as a sealed MCAP metadata map (every value a string; floats in repr, exact)."""
    return seal_metadata({f.name: repr(v) if isinstance(v, float) else str(v) for f in dataclasses.fields(obj)
                          for v in [getattr(obj, f.name)]})


def from_metadata(cls: type, data: dict[str, str]) -> object:
    """The dataclass `cls` an MCAP metadata map written by to_metadata stands for."""
    hints = typing.get_type_hints(cls)
    try:
        kwargs = {k: hints[k](v) if hints[k] in (int, float) else v for k, v in data.items()}
        return cls(**kwargs)
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"metadata for {cls.__name__} does not decode: {exc}") from None
