"""ROS bags as a frame source: a range and an amplitude sensor_msgs/Image topic and a CameraInfo topic, paired by
header stamp, become Frames. Reads ROS 1 .bag files and ROS 2 bags (a directory with metadata.yaml, or a bare
.db3 or .mcap storage file) through the `rosbags` package.

The defaults are what the SwissRanger ROS driver (swissranger_camera, launched as node "SwissRanger") publishes:
distance/image_raw16 (mono16 in device units: raw / 65535 x c / (2 f_mod), 0xFFFF = no return),
intensity/image_raw16 (mono16) and camera_info, all three with the same header stamp. Its distance/image_raw and
intensity/image_raw are 8-bit display images (scaled by 255/65535) and are refused as range.

Range: 32FC1 in metres as it is (REP 118); 16UC1/mono16 in device units (SwissRanger) or millimetres (REP 118,
0 = no return), per RangeOptions.range_unit. Radial range (along each pixel's ray, as tofd and the SwissRanger
measure) or z-depth (along the optical axis, REP 118's depth), converted with the intrinsics' unit rays:
radial = z / ray_z. Amplitude: mono8/8UC1, mono16/16UC1 or 32FC1, as float32. Intrinsics: CameraInfo's K
(ROS and tofd both put pixel centres at integer coordinates), width and height; distortion is not modelled by
tofd and is ignored (logged). Any image size works: the intrinsics decide.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from mcap.stream_reader import StreamReader

from drivers.frame import DeviceInfo, Frame, Registers
from drivers.intrinsics import Intrinsics
from drivers.recording.format import PROFILE
from drivers.source import DriverError, FrameSource
from drivers.usb import protocol

log = logging.getLogger(__name__)

IMAGE_TYPE = "sensor_msgs/msg/Image"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
RANGE_ENCODINGS: dict[str, str] = {"32FC1": "f4", "16UC1": "u2", "mono16": "u2"}
"""Range image encoding -> numpy dtype (byte order from the message's is_bigendian)."""
AMPLITUDE_ENCODINGS: dict[str, str] = {**RANGE_ENCODINGS, "mono8": "u1", "8UC1": "u1"}
"""Amplitude image encoding -> numpy dtype."""
RANGE_UNITS = ("device", "mm")
DEPTH_CONVENTIONS = ("radial", "z")
MAX_PENDING_STAMPS = 256
"""Stamps waiting for their other messages; an older incomplete one is given up as unpaired (bags interleave the
messages of one frame closely, so this only bounds memory)."""


class BagError(DriverError):
    """A bag that cannot be imported: unreadable, a topic missing or of the wrong type, an image tofd cannot use."""


@dataclass(frozen=True, slots=True)
class RangeOptions:
    """Which topics hold a frame and how its range is encoded (defaults: the SwissRanger ROS driver)."""

    range_topic: str = "/SwissRanger/distance/image_raw16"
    amplitude_topic: str = "/SwissRanger/intensity/image_raw16"
    camera_info_topic: str = "/SwissRanger/camera_info"
    range_unit: Literal["device", "mm"] = "device"  # 16-bit range images: SwissRanger device units or millimetres
    depth: Literal["radial", "z"] = "radial"  # radial range along each pixel's ray, or z-depth along the axis
    mod_freq_mhz: float = 20.0  # device units: the modulation frequency (SR3000 power-up: 20 MHz -> 7.49 m)

    def validate(self) -> None:
        if self.range_unit not in RANGE_UNITS:
            raise ValueError(f"range unit {self.range_unit!r} is not one of {', '.join(RANGE_UNITS)}")
        if self.depth not in DEPTH_CONVENTIONS:
            raise ValueError(f"depth {self.depth!r} is not one of {', '.join(DEPTH_CONVENTIONS)}")
        if not (np.isfinite(self.mod_freq_mhz) and self.mod_freq_mhz > 0):
            raise ValueError(f"modulation frequency {self.mod_freq_mhz!r} MHz must be > 0")

    @property
    def topics(self) -> dict[str, str]:
        """Role ("range", "amplitude", "camera_info") -> topic."""
        return {"range": self.range_topic, "amplitude": self.amplitude_topic, "camera_info": self.camera_info_topic}


def is_rosbag(path: str | Path) -> bool:
    """Whether `path` is a ROS bag rather than a tofd recording: a .bag or .db3 file, a directory (a ROS 2 bag), or
    an .mcap file whose MCAP profile is not tofd's (ROS 2 writes "ros2")."""
    path = Path(path)
    if path.suffix in (".bag", ".db3") or path.is_dir():
        return True
    if path.suffix != ".mcap":
        return False
    try:
        with open(path, "rb") as f:
            header = next(StreamReader(f, skip_magic=False).records)
    except Exception:  # noqa: BLE001 (an unreadable file is left to the recording reader, which says why)
        return False
    return getattr(header, "profile", PROFILE) != PROFILE


def _reader(path: Path) -> Any:
    """An open rosbags AnyReader on `path` (a ROS 1 bag by its .bag suffix, else a ROS 2 bag)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise BagError(f"{path}: no such file or directory")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.LATEST))
        reader.open()
    except Exception as exc:  # noqa: BLE001 (whatever rosbags cannot parse is an unreadable bag)
        raise BagError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})") from None
    return reader


def _field(msg: object, name: str) -> Any:
    """A CameraInfo matrix by its ROS 2 name (k, d) or ROS 1 name (K, D)."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())


def image_plane(msg: Any, encodings: dict[str, str], topic: str) -> np.ndarray:
    """(height, width) array of a sensor_msgs/Image in its own dtype (native byte order), rows of `step` bytes."""
    dtype_code = encodings.get(msg.encoding)
    if dtype_code is None:
        raise BagError(f"{topic}: image encoding {msg.encoding!r} is not supported (supported: {', '.join(encodings)})")
    dtype = np.dtype(dtype_code).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = w * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < row_bytes or data.size < h * step:
        raise BagError(f"{topic}: a {w}x{h} {msg.encoding} image has {data.size} bytes in rows of {step}, expected "
                       f"{h} rows of at least {row_bytes} bytes")
    rows = np.ascontiguousarray(data[:h * step].reshape(h, step)[:, :row_bytes])
    return rows.view(dtype).reshape(h, w).astype(dtype.newbyteorder("="))


def camera_intrinsics(msg: Any, topic: str) -> Intrinsics:
    """Intrinsics of a sensor_msgs/CameraInfo: K's focal lengths and principal point, its width and height."""
    k = np.asarray(_field(msg, "k"), dtype=np.float64)
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    if not (fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()) or msg.width < 1 or msg.height < 1:
        raise BagError(f"{topic}: no usable calibration (K = {k.tolist()}, {msg.width}x{msg.height}): tofd needs "
                       "focal lengths > 0 and the image size")
    return Intrinsics(int(msg.width), int(msg.height), fx, fy, cx, cy)


def range_plane(image: np.ndarray, options: RangeOptions, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W) float32 radial range in metres (NaN where no return) from a range image's array."""
    if image.dtype == np.float32:
        metres = image
    elif options.range_unit == "device":
        metres = protocol.raw_to_range_m(image, round(options.mod_freq_mhz * 1000))
    else:
        metres = image.astype(np.float32) * np.float32(1e-3)
        metres[image == 0] = np.nan
    if options.depth == "z":
        metres = intrinsics.radial_from_z(metres).astype(np.float32)
    return metres


class RosbagSource(FrameSource):
    """Frames of a ROS bag: each header stamp with a range image, an amplitude image and a CameraInfo.

    Frame counters count the paired frames from 0; the device timestamp is the header stamp, the host times are
    the bag's receive time of the range image; the device is backend "rosbag", model = the header's frame_id.
    Messages whose stamp never completes a frame are counted in counters["unpaired_<role>"]. Opening checks the
    topics (BagError names a missing one and lists the bag's topics); iterating raises BagError at the first
    image tofd cannot use.
    """

    def __init__(self, path: str | Path, options: RangeOptions | None = None) -> None:
        super().__init__()
        options = options or RangeOptions()
        options.validate()
        self.path, self.options = Path(path), options
        self._reader = _reader(self.path)
        try:
            self.range_messages = self._check_topics()
        except BagError:
            self._reader.close()
            raise
        index = protocol.mod_freq_index(round(options.mod_freq_mhz * 1000))
        self._registers = Registers() if index is None else Registers(mod_freq_index=index)
        self.intrinsics: Intrinsics | None = None
        """The calibration of every frame so far (None before the first)."""
        self._distortion_logged = False

    def _check_topics(self) -> int:
        """Number of range messages, after checking that every topic is in the bag with its message type."""
        topics = self._reader.topics
        for role, topic in self.options.topics.items():
            expected = CAMERA_INFO_TYPE if role == "camera_info" else IMAGE_TYPE
            if topic not in topics:
                have = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items())) or "none"
                raise BagError(f"{self.path}: no {role} topic {topic}; the bag has: {have}")
            if topics[topic].msgtype != expected:
                raise BagError(f"{self.path}: {role} topic {topic} is {topics[topic].msgtype}, expected {expected}")
        return int(topics[self.options.range_topic].msgcount)

    def close(self) -> None:
        super().close()
        if self._reader.stack is not None:
            self._reader.close()

    def _frame(self, counter: int, parts: dict[str, tuple[Any, int]]) -> Frame:
        """The Frame of one stamp's range image, amplitude image and CameraInfo (each with its receive time)."""
        (rng, log_ns), (amp, _), (info, _) = parts["range"], parts["amplitude"], parts["camera_info"]
        intrinsics = camera_intrinsics(info, self.options.camera_info_topic)
        if self.intrinsics is None:
            self.intrinsics = intrinsics
        elif intrinsics != self.intrinsics:
            raise BagError(f"{self.options.camera_info_topic}: the calibration changes at stamp {_seconds(info)} "
                           f"({self.intrinsics} -> {intrinsics}); a tofd recording holds one camera calibration")
        if not self._distortion_logged and np.any(np.asarray(_field(info, "d")) != 0):
            log.warning("%s: distortion %s is ignored (tofd uses a pinhole model)", self.options.camera_info_topic,
                        np.asarray(_field(info, "d")).tolist())
            self._distortion_logged = True
        range_image = image_plane(rng, RANGE_ENCODINGS, self.options.range_topic)
        amplitude = image_plane(amp, AMPLITUDE_ENCODINGS, self.options.amplitude_topic).astype(np.float32)
        sizes = {"range image": range_image.shape, "amplitude image": amplitude.shape,
                 "camera_info": intrinsics.shape}
        if len(set(sizes.values())) > 1:
            raise BagError(f"stamp {_seconds(rng)}: sizes differ: "
                           + ", ".join(f"{name} {w}x{h}" for name, (h, w) in sizes.items()))
        return Frame(range_m=range_plane(range_image, self.options, intrinsics), amplitude=amplitude,
                     frame_counter=counter, timestamp_us=_stamp(rng) // 1000, host_monotonic_s=log_ns / 1e9,
                     host_wall_s=log_ns / 1e9, intrinsics=intrinsics,
                     device=DeviceInfo(serial="", backend="rosbag", model=rng.header.frame_id),
                     registers=self._registers)

    def _messages(self, roles: dict[str, str]) -> Iterator[tuple[str, Any, int]]:
        """(role, decoded message, receive time ns) of the topics' messages in bag order."""
        connections = [c for c in self._reader.connections if c.topic in roles]
        try:
            for connection, log_ns, raw in self._reader.messages(connections=connections):
                yield roles[connection.topic], self._reader.deserialize(raw, connection.msgtype), log_ns
        except Exception as exc:  # noqa: BLE001 (a message rosbags cannot read or decode is a damaged bag)
            raise BagError(f"{self.path}: unreadable message ({type(exc).__name__}: {exc})") from None

    def __iter__(self) -> Iterator[Frame]:
        """Frames in the order their last message arrives in the bag."""
        roles = {topic: role for role, topic in self.options.topics.items()}
        pending: dict[int, dict[str, tuple[Any, int]]] = {}
        counter = 0
        for role, msg, log_ns in self._messages(roles):
            if self.closed:
                return
            parts = pending.setdefault(_stamp(msg), {})
            if role in parts:  # a second message of this role and stamp: the first one stays unpaired
                self.counters[f"unpaired_{role}"] += 1
            parts[role] = (msg, log_ns)
            if len(parts) == len(roles):
                del pending[_stamp(msg)]
                yield self._frame(counter, parts)
                counter += 1
            while len(pending) > MAX_PENDING_STAMPS:
                self._unpaired(pending.pop(next(iter(pending))))
        for parts in pending.values():
            self._unpaired(parts)

    def _unpaired(self, parts: dict[str, tuple[Any, int]]) -> None:
        for role in parts:
            self.counters[f"unpaired_{role}"] += 1


def _stamp(msg: Any) -> int:
    """A message's header stamp in nanoseconds."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _seconds(msg: Any) -> str:
    """A message's header stamp as ROS prints it, e.g. "1700000000.033333000" (seconds)."""
    return f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"
