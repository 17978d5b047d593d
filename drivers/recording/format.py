"""Layout of a tofd recording (an MCAP file, format 2): its records, channels and the messages of one frame.

The images use Foxglove's protobuf schemas (foxglove.RawImage, foxglove.CameraCalibration) rather than ROS 2's
sensor_msgs, because Foxglove and Rerun's MCAP importer both decode them natively and protobuf needs no ROS
message definitions or CDR codec, while it also describes tofd's own per-frame header (drivers/recording/schemas.py).

A recording is an MCAP file (https://mcap.dev) with profile "tofd":

- Metadata "tofd.recording" (format version, software version, creation time), an attachment "config.json"
  (the service configuration), then the SCHEMAS and CHANNELS records (fixed ids), then, before the first
  frame, metadata "tofd.intrinsics", "tofd.device" and "tofd.registers" (an SR3000 source) or "tofd.sensor" (any
  other camera: its signal and settings, tofd.drivers.frame.SensorInfo) (every metadata map sealed with a CRC).
- One zstd-compressed, CRC-32-checked chunk per frame holding its messages in channel order:
  /camera/frame (tofd.FrameHeader: counter, device and host times, intrinsics, device, registers or sensor,
  ground truth, plane codecs), /camera/range and /camera/amplitude (foxglove.RawImage, frame_id IMAGE_FRAME_ID) and
  /camera/calibration (foxglove.CameraCalibration). Every message: log_time = host wall clock (ns),
  publish_time = device timestamp (ns), sequence = frame counter (mod 2**32).
- Planes are stored losslessly: "16UC1" with the header's scale and invalid raw value when the plane is exactly
  float32(float64(raw) * scale) (what the USB backend delivers; range is then in device units, amplitude in
  sensor units), else "32FC1" (the float32 values themselves).
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
import zlib
from dataclasses import dataclass

import numpy as np

from tofd.drivers import sr3000
from tofd.drivers.errors import DataError
from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording import schemas

FORMAT_VERSION = 2
PROFILE = "tofd"
META_RECORDING = "tofd.recording"
META_INTRINSICS = "tofd.intrinsics"
META_DEVICE = "tofd.device"
META_REGISTERS = "tofd.registers"
META_SENSOR = "tofd.sensor"
CONFIG_ATTACHMENT = "config.json"
METADATA_CRC_KEY = "crc32"
MESSAGE_ENCODING = "protobuf"
IMAGE_FRAME_ID = "camera"
"""frame_id of the images and the calibration: the camera's optical frame (x right, y down, z forward)."""


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """One channel of a recording: its fixed id, topic, schema name and role in a frame."""

    id: int
    topic: str
    schema: str
    role: str


SCHEMAS = ("tofd.FrameHeader", "foxglove.RawImage", "foxglove.CameraCalibration")
"""Schema names in id order (ids 1, 2, 3)."""
CHANNELS = (
    ChannelSpec(1, "/camera/frame", "tofd.FrameHeader", "header"),
    ChannelSpec(2, "/camera/range", "foxglove.RawImage", "range_m"),
    ChannelSpec(3, "/camera/amplitude", "foxglove.RawImage", "amplitude"),
    ChannelSpec(4, "/camera/calibration", "foxglove.CameraCalibration", "calibration"),
)
"""Channels in id order, which is also the order of a frame's messages in its chunk."""
ROLE_BY_ID = {c.id: c.role for c in CHANNELS}
_ENCODINGS: dict[str, np.dtype] = {"16UC1": np.dtype("<u2"), "32FC1": np.dtype("<f4")}


class FormatError(DataError):
    """A frame message or metadata record that does not follow this layout."""


def channel_role(topic: str, message_encoding: str) -> str | None:
    """Role of a format-2 channel in a frame ("header", "range_m", "amplitude", "calibration"), or None."""
    if message_encoding != MESSAGE_ENCODING:
        return None
    return next((c.role for c in CHANNELS if c.topic == topic), None)


def range_scales_m(registers: Registers | None) -> tuple[float, ...]:
    """Candidate metres per raw distance unit at the frame's modulation frequency (raw/65535 * c/(2 f)):
    rounded to float32 as the USB backend multiplies (tofd.drivers.sr3000.raw_to_range_m), and exact; none
    without SR3000 registers (such a range plane is stored as float32)."""
    if registers is None:
        return ()
    scale = sr3000.non_ambiguity_range_m(sr3000.mod_freq_khz(registers.mod_freq_index)) / 65535.0
    return float(np.float32(scale)), scale


def raw_to_plane(raw: np.ndarray, scale: float, invalid: int | None) -> np.ndarray:
    """float32(float64(raw) * scale), NaN where raw == invalid: a new, writable array."""
    out = (raw.astype(np.float64) * scale).astype(np.float32)
    if invalid is not None:
        out[raw == invalid] = np.nan
    return out


def encode_plane(plane: np.ndarray, scales: tuple[float, ...], invalid: int | None
                 ) -> tuple[str, float, int | None, bytes]:
    """(image encoding, scale, invalid, pixel bytes) of a float32 plane: "16UC1" with the first of `scales` that
    reproduces it bit for bit, else "32FC1" (scale 1, no invalid value)."""
    valid = np.isfinite(plane)
    for scale in scales:
        with np.errstate(invalid="ignore", divide="ignore"):
            raw = np.where(valid, np.rint(plane / np.float64(scale)), -1.0 if invalid is None else invalid)
        if not np.all((raw >= 0) & (raw <= 0xFFFF)):
            continue
        raw16 = raw.astype("<u2")
        if np.array_equal(raw_to_plane(raw16, scale, invalid).view(np.uint32), plane.view(np.uint32)):
            return "16UC1", scale, invalid, raw16.tobytes()
    return "32FC1", 1.0, None, plane.astype("<f4", copy=False).tobytes()


def _check_plane(name: str, plane: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    if not isinstance(plane, np.ndarray) or plane.dtype != np.float32 or plane.shape != shape:
        got = f"{getattr(plane, 'dtype', type(plane).__name__)} {getattr(plane, 'shape', '')}"
        raise ValueError(f"frame.{name}: expected float32 array of shape {shape}, got {got}")
    return np.ascontiguousarray(plane)


def message_times(frame: Frame) -> tuple[int, int, int]:
    """MCAP (log_time, publish_time, sequence) of a frame's messages: host wall clock (ns), device clock (ns),
    frame counter mod 2**32; ValueError when a time does not fit MCAP's unsigned 64-bit nanoseconds."""
    wall, device = frame.host_wall_s, frame.timestamp_us
    if not (math.isfinite(wall) and 0 <= wall * 1e9 < 2.0**64):
        raise ValueError(f"frame.host_wall_s: expected Unix time in seconds, got {wall!r}")
    if not (isinstance(device, int) and 0 <= device * 1000 < 2**64):
        raise ValueError(f"frame.timestamp_us: expected microseconds in [0, 2**64 / 1000), got {device!r}")
    return int(round(wall * 1e9)), device * 1000, int(frame.frame_counter) & 0xFFFFFFFF


def _header(frame: Frame, codecs: dict[str, tuple[float, int | None]]) -> bytes:
    msg = schemas.frame_header_class()()
    try:
        msg.frame_counter, msg.timestamp_us = frame.frame_counter, frame.timestamp_us
    except (TypeError, ValueError) as exc:
        raise ValueError(f"frame counter {frame.frame_counter!r} or timestamp {frame.timestamp_us!r} us is not "
                         f"a 64-bit integer: {exc}") from None
    msg.host_monotonic_s, msg.host_wall_s = frame.host_monotonic_s, frame.host_wall_s
    parts = [("intrinsics", frame.intrinsics.to_dict()), ("device", dataclasses.asdict(frame.device))]
    if frame.registers is not None:
        parts.append(("registers", dataclasses.asdict(frame.registers)))
    for name, fields in parts:
        getattr(msg, name).SetInParent()
        for key, value in fields.items():
            if isinstance(value, list):
                getattr(getattr(msg, name), key).extend(value)
            else:
                setattr(getattr(msg, name), key, value)
    if (gt := frame.ground_truth) is not None:
        msg.ground_truth.nose_u, msg.ground_truth.nose_v = gt.nose_px
        msg.ground_truth.visible = gt.visible
        if gt.nose_xyz_m is not None:
            xyz = msg.ground_truth.nose_xyz_m
            xyz.x, xyz.y, xyz.z = gt.nose_xyz_m
    if (sensor := frame.sensor) is not None:
        msg.sensor.SetInParent()
        for key, value in sensor.to_dict().items():
            if key == "settings":
                for k, v in sorted(sensor.settings.items()):
                    msg.sensor.settings.add(key=k, value=v)
            elif value is not None:
                setattr(msg.sensor, key, value)
    for name, (scale, invalid) in codecs.items():
        codec = getattr(msg, "range" if name == "range_m" else name)
        codec.scale = scale
        if invalid is not None:
            codec.invalid = invalid
    return msg.SerializeToString()


def _timestamp(ns: int) -> dict[str, int]:
    return {"seconds": ns // 1_000_000_000, "nanos": ns % 1_000_000_000}


FOXGLOVE_DISTORTION_MODELS = {"none": "plumb_bob", "plumb_bob": "plumb_bob",
                              "rational_polynomial": "rational_polynomial", "equidistant": "kannala_brandt"}
"""foxglove.CameraCalibration's name of each lens model (a pinhole: plumb_bob with zero coefficients)."""


def _calibration(intr: Intrinsics, ns: int) -> bytes:
    fx, fy, cx, cy = intr.fx, intr.fy, intr.cx, intr.cy
    return schemas.CameraCalibration(
        timestamp=_timestamp(ns), frame_id=IMAGE_FRAME_ID, width=intr.width, height=intr.height,
        distortion_model=FOXGLOVE_DISTORTION_MODELS[intr.distortion_model],
        D=list(intr.distortion) if not intr.is_pinhole else [0.0] * 5,
        K=[fx, 0, cx, 0, fy, cy, 0, 0, 1], R=[1, 0, 0, 0, 1, 0, 0, 0, 1],
        P=[fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]).SerializeToString()


def encode_frame(frame: Frame) -> list[bytes]:
    """The messages of one frame, in CHANNELS order (ValueError for a frame the format cannot hold)."""
    shape = frame.intrinsics.shape
    ns = message_times(frame)[0]
    planes = {"range_m": (range_scales_m(frame.registers), sr3000.RAW_INVALID), "amplitude": ((1.0,), None)}
    images, codecs = [], {}
    for name, (scales, invalid) in planes.items():
        plane = _check_plane(name, getattr(frame, name), shape)
        encoding, scale, used_invalid, data = encode_plane(plane, scales, invalid)
        codecs[name] = (scale, used_invalid)
        images.append(schemas.RawImage(
            timestamp=_timestamp(ns), frame_id=IMAGE_FRAME_ID, width=shape[1], height=shape[0], encoding=encoding,
            step=shape[1] * _ENCODINGS[encoding].itemsize, data=data).SerializeToString())
    return [_header(frame, codecs), *images, _calibration(frame.intrinsics, ns)]


def _plane(image_data: bytes, codec: typing.Any, shape: tuple[int, int], name: str) -> np.ndarray:
    image = schemas.RawImage.FromString(image_data)
    dtype = _ENCODINGS.get(image.encoding)
    if dtype is None:
        raise FormatError(f"{name} image has encoding {image.encoding!r}, expected one of {sorted(_ENCODINGS)}")
    h, w = shape
    data = image.data  # protobuf copies a bytes field out at every access
    if (image.height, image.width, image.step, len(data)) != (h, w, w * dtype.itemsize, h * w * dtype.itemsize):
        raise FormatError(f"{name} image is {image.width}x{image.height} (step {image.step}, {len(data)} "
                          f"bytes), expected {w}x{h} {image.encoding}")
    values = np.frombuffer(data, dtype=dtype).reshape(shape)
    if image.encoding == "32FC1":
        return values.astype(np.float32)  # a copy: writable
    return raw_to_plane(values, codec.scale, codec.invalid if codec.HasField("invalid") else None)


def decode_frame(header_data: bytes, range_data: bytes, amplitude_data: bytes) -> Frame:
    """The Frame of one header message and its two images (FormatError if they do not follow the layout)."""
    try:
        h = schemas.frame_header_class().FromString(header_data)
        gt = None
        if h.HasField("ground_truth"):
            g = h.ground_truth
            xyz = (g.nose_xyz_m.x, g.nose_xyz_m.y, g.nose_xyz_m.z) if g.HasField("nose_xyz_m") else None
            gt = GroundTruth(nose_px=(g.nose_u, g.nose_v), visible=g.visible, nose_xyz_m=xyz)
        fields = {name: {f.name: getattr(getattr(h, name), f.name) for f in getattr(h, name).DESCRIPTOR.fields}
                  for name in ("device", "registers")}
        registers = Registers(**fields["registers"]) if h.HasField("registers") else None
        # the fields present: headers written before lens models have none of the distortion fields (a pinhole)
        intrinsics = Intrinsics.from_dict({f.name: v if isinstance(v, (str, int, float)) else list(v)
                                           for f, v in h.intrinsics.ListFields()})
        return Frame(
            range_m=_plane(range_data, h.range, intrinsics.shape, "range"),
            amplitude=_plane(amplitude_data, h.amplitude, intrinsics.shape, "amplitude"),
            frame_counter=h.frame_counter, timestamp_us=h.timestamp_us,
            host_monotonic_s=h.host_monotonic_s, host_wall_s=h.host_wall_s,
            intrinsics=intrinsics, device=DeviceInfo(**fields["device"]), registers=registers,
            ground_truth=gt, sensor=_sensor(h.sensor) if h.HasField("sensor") else None)
    except FormatError:
        raise
    except Exception as exc:  # noqa: BLE001 (protobuf's DecodeError, bad shapes: all mean a malformed frame)
        raise FormatError(f"frame messages do not decode: {type(exc).__name__}: {exc}") from None


def _sensor(msg: typing.Any) -> SensorInfo:
    """The SensorInfo of a tofd.Sensor message (absent optional fields: None)."""
    return SensorInfo.from_dict({f.name: {s.key: s.value for s in msg.settings} if f.name == "settings" else
                                 getattr(msg, f.name) if msg.HasField(f.name) else None
                                 for f in msg.DESCRIPTOR.fields})


def _metadata_crc(data: dict[str, str]) -> str:
    return str(zlib.crc32(json.dumps(data, sort_keys=True, separators=(",", ":")).encode()))


def seal_metadata(data: dict[str, str]) -> dict[str, str]:
    """`data` plus METADATA_CRC_KEY: CRC-32 of its canonical JSON (MCAP metadata records carry no CRC)."""
    return {**data, METADATA_CRC_KEY: _metadata_crc(data)}


def check_metadata(name: str, data: dict[str, str]) -> dict[str, str]:
    """`data` without its METADATA_CRC_KEY; FormatError if that CRC does not match (early format-1 files have
    none: their metadata is checked against the frames instead)."""
    if METADATA_CRC_KEY not in data:
        return data
    body = {k: v for k, v in data.items() if k != METADATA_CRC_KEY}
    if _metadata_crc(body) != data[METADATA_CRC_KEY]:
        raise FormatError(f"metadata {name!r} fails its CRC")
    return body


def to_metadata(obj: typing.Any) -> dict[str, str]:
    """A dataclass as a sealed MCAP metadata map (every value a string; floats in repr, exact; tuples as JSON)."""
    return seal_metadata({f.name: repr(v) if isinstance(v, float) else json.dumps(v) if isinstance(v, tuple)
                          else str(v) for f in dataclasses.fields(obj) for v in [getattr(obj, f.name)]})


def sensor_metadata(sensor: SensorInfo) -> dict[str, str]:
    """A SensorInfo as a sealed MCAP metadata map: each field as JSON (settings a JSON object)."""
    return seal_metadata({key: json.dumps(value) for key, value in sensor.to_dict().items()})


def sensor_from_metadata(data: dict[str, str]) -> SensorInfo:
    """The SensorInfo a sensor_metadata map stands for."""
    try:
        return SensorInfo.from_dict({key: json.loads(value) for key, value in data.items()})
    except (TypeError, ValueError) as exc:
        raise FormatError(f"metadata for SensorInfo does not decode: {exc}") from None


def from_metadata(cls: type, data: dict[str, str]) -> object:
    """The dataclass `cls` an MCAP metadata map written by to_metadata stands for."""
    hints = typing.get_type_hints(cls)
    try:
        kwargs = {k: hints[k](v) if hints[k] in (int, float) else
                  tuple(json.loads(v)) if typing.get_origin(hints[k]) is tuple else v for k, v in data.items()}
        return cls(**kwargs)
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"metadata for {cls.__name__} does not decode: {exc}") from None
