"""ROS 1 wire format read field by field, for the messages whose bytes do not follow the definition stored in
their bag: librealsense's and the Orbbec SDK's sensor_msgs/Image carry fields after `data` that the definition
does not declare (a float32 depth unit, then Orbbec's frame number and timestamps), and the Orbbec SDK declares
`uint8 propertyId` but writes a uint32. A generic deserializer refuses such messages (size mismatch) or
misreads them, so these are read here with the layout their writers use.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from tofd.drivers.errors import DataError


class WireError(DataError):
    """A message shorter than its fields, or a length field pointing past its end."""


class Cursor:
    """Reads little-endian ROS 1 fields from the front of a message's bytes."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.data, self.pos = memoryview(data), 0

    @property
    def remaining(self) -> int:
        return len(self.data) - self.pos

    def take(self, n: int) -> memoryview:
        if n < 0 or n > self.remaining:
            raise WireError(f"needs {n} bytes at offset {self.pos}, has {self.remaining}")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def scalar(self, code: str) -> int | float:
        size = struct.calcsize("<" + code)
        value: int | float = struct.unpack("<" + code, self.take(size))[0]
        return value

    def string(self) -> str:
        return bytes(self.take(int(self.scalar("I")))).decode("utf-8", "replace")

    def u8_array(self) -> np.ndarray:
        return np.frombuffer(self.take(int(self.scalar("I"))), np.uint8)

    def floats(self, n: int) -> tuple[float, ...]:
        return struct.unpack(f"<{n}f", self.take(4 * n))


@dataclass(frozen=True, slots=True)
class Header:
    """std_msgs/Header (ROS 1)."""

    seq: int
    stamp_ns: int
    frame_id: str


def header(cursor: Cursor) -> Header:
    seq, sec, nsec = (int(cursor.scalar("I")) for _ in range(3))
    return Header(seq, sec * 1_000_000_000 + nsec, cursor.string())


@dataclass(frozen=True, slots=True)
class ExtendedImage:
    """A sensor_msgs/Image with the fields librealsense (<= 2.56) and the Orbbec SDK v2 append after `data`.

    depth_units: metres (librealsense) or millimetres (Orbbec) per unit, 0 when not written; number and
    timestamp_usec: the device's frame number and timestamp (Orbbec only, else None).
    """

    header: Header
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: np.ndarray
    depth_units: float = 0.0
    number: int | None = None
    timestamp_usec: int | None = None


def extended_image(raw: bytes | memoryview) -> ExtendedImage:
    """An ExtendedImage from a ROS 1 serialized sensor_msgs/Image with or without the appended fields."""
    c = Cursor(raw)
    head = header(c)
    height, width = int(c.scalar("I")), int(c.scalar("I"))
    encoding, is_bigendian, step = c.string(), int(c.scalar("B")), int(c.scalar("I"))
    data = c.u8_array()
    units = float(c.scalar("f")) if c.remaining >= 4 else 0.0
    number = timestamp = None
    if c.remaining >= 16:
        number, timestamp = int(c.scalar("Q")), int(c.scalar("Q"))
    return ExtendedImage(head, height, width, encoding, is_bigendian, step, data, units, number, timestamp)


@dataclass(frozen=True, slots=True)
class Property:
    """The Orbbec SDK's custom_msg/OBProperty: a property id and its raw value bytes."""

    header: Header
    property_id: int
    data: bytes


def ob_property(raw: bytes | memoryview) -> Property:
    c = Cursor(raw)
    head = header(c)
    return Property(head, int(c.scalar("I")), bytes(c.u8_array()))


@dataclass(frozen=True, slots=True)
class StreamProfile:
    """The Orbbec SDK's custom_msg/OBStreamProfileInfo of a video stream: size, rate, intrinsics [fx, fy, cx, cy],
    distortion [k1..k6, p1, p2] and the OBCameraDistortionModel number."""

    header: Header
    stream_type: int
    format: int
    width: int
    height: int
    fps: int
    intrinsic: tuple[float, ...]
    distortion: tuple[float, ...]
    distortion_model: int


def ob_stream_profile(raw: bytes | memoryview) -> StreamProfile:
    c = Cursor(raw)
    head = header(c)
    stream_type, fmt = int(c.scalar("B")), int(c.scalar("B"))
    c.floats(12)  # rotation and translation to the colour camera
    width, height, fps = (int(c.scalar("H")) for _ in range(3))
    intrinsic, distortion = c.floats(4), c.floats(8)
    return StreamProfile(head, stream_type, fmt, width, height, fps, intrinsic, distortion, int(c.scalar("B")))


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """The identity fields of the Orbbec SDK's custom_msg/OBDeviceInfo."""

    name: str
    serial: str
    firmware: str
    vid: int
    pid: int


def ob_device_info(raw: bytes | memoryview) -> DeviceInfo:
    c = Cursor(raw)
    header(c)
    name, _full_name, _asic = c.string(), c.string(), c.string()
    vid, pid = int(c.scalar("H")), int(c.scalar("H"))
    _uid, serial, firmware = c.string(), c.string(), c.string()
    return DeviceInfo(name, serial, firmware, vid, pid)
