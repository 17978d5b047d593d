"""ROS bags of camera drivers as a frame source: a range and an amplitude image topic and a CameraInfo topic,
paired by header stamp, become Frames. Reads ROS 1 .bag files and ROS 2 bags (a directory with metadata.yaml,
or a bare .db3 or .mcap storage file) through the `rosbags` package (tofd.drivers.bags.scan).

The topics are those of the driver the bag's topics show (tofd.drivers.bags.driver_layouts: swissranger_camera,
orbbec_camera, azure_kinect_ros_driver, realsense2_camera, royale), each overridable by RangeOptions. The
SwissRanger ROS driver publishes distance/image_raw16 (mono16 in device units: raw / 65535 x c / (2 f_mod),
0xFFFF = no return), intensity/image_raw16 (mono16) and camera_info, all three with the same header stamp; its
distance/image_raw and intensity/image_raw are 8-bit display images and are refused as range. The ROS 2 TOF
drivers publish z-depth (REP 118: 16UC1 millimetres, 0 = no return, or 32FC1 metres) and an infrared or
gray-value image (mono8, mono16 or 32FC1), raw or through image_transport's compressed / compressedDepth (PNG).

Range: 32FC1 in metres as it is; 16-bit in device units (SwissRanger) or millimetres, per RangeOptions.range_unit
(default: the driver's). Radial range (along each pixel's ray, as tofd and the SwissRanger measure) or z-depth,
converted with the CameraInfo's undistorted unit rays: radial = z / ray_z. Amplitude: as float32 in the
image's own units. Intrinsics: CameraInfo's K, size and lens (tofd.drivers.bags.camera_info: plumb_bob,
rational_polynomial, equidistant). Any image size works: the intrinsics decide. SwissRanger device units at an
SR3000 modulation frequency make an SR3000 frame (Registers with that MOD_FREQ); every other bag's frames carry
no registers but a SensorInfo (depth unit, what the amplitude is, the driver, topics and options as settings).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from tofd.drivers import sr3000
from tofd.drivers.bags.camera_info import camera_info_intrinsics
from tofd.drivers.bags.driver_layouts import (
    AMPLITUDE_KINDS,
    CAMERA_INFO_TYPE,
    Layout,
    describe_topics,
    detect_layout,
    no_layout_error,
)
from tofd.drivers.bags.images import AMPLITUDE_ENCODINGS, IMAGE_TYPE, IMAGE_TYPES, RANGE_ENCODINGS, plane
from tofd.drivers.bags.join import StreamJoin
from tofd.drivers.bags.scan import BagError, BagReader, DamagedMessage, RawMessage
from tofd.drivers.bags.source import BagSource
from tofd.drivers.depth import depth_metres
from tofd.drivers.frame import DeviceInfo, Frame, Registers
from tofd.drivers.intrinsics import Intrinsics

__all__ = ["AMPLITUDE_ENCODINGS", "CAMERA_INFO_TYPE", "IMAGE_TYPE", "RANGE_ENCODINGS", "BagError", "RangeOptions",
           "RosbagSource"]

log = logging.getLogger(__name__)

RANGE_UNITS = ("device", "mm")
DEPTH_CONVENTIONS = ("radial", "z")


@dataclass(frozen=True, slots=True)
class RangeOptions:
    """Which topics hold a frame and how its range is encoded; None = what the bag's driver publishes
    (tofd.drivers.bags.driver_layouts)."""

    range_topic: str | None = None
    amplitude_topic: str | None = None
    camera_info_topic: str | None = None
    range_unit: Literal["device", "mm"] | None = None  # 16-bit range: SwissRanger device units or millimetres
    depth: Literal["radial", "z"] | None = None  # radial range along each pixel's ray, or z-depth along the axis
    mod_freq_mhz: float = 20.0  # device units: the modulation frequency (SR3000 power-up: 20 MHz -> 7.49 m)

    def validate(self) -> None:
        if self.range_unit is not None and self.range_unit not in RANGE_UNITS:
            raise ValueError(f"range unit {self.range_unit!r} is not one of {', '.join(RANGE_UNITS)}")
        if self.depth is not None and self.depth not in DEPTH_CONVENTIONS:
            raise ValueError(f"depth {self.depth!r} is not one of {', '.join(DEPTH_CONVENTIONS)}")
        if not (np.isfinite(self.mod_freq_mhz) and self.mod_freq_mhz > 0):
            raise ValueError(f"modulation frequency {self.mod_freq_mhz!r} MHz must be > 0")

    @property
    def topics(self) -> dict[str, str | None]:
        """Role ("range", "amplitude", "camera_info") -> topic (None: the driver's)."""
        return {"range": self.range_topic, "amplitude": self.amplitude_topic, "camera_info": self.camera_info_topic}


@dataclass(frozen=True, slots=True)
class ResolvedOptions:
    """The topics and encoding of one bag: RangeOptions over its driver's layout."""

    topics: dict[str, str]
    range_unit: Literal["device", "mm"]
    depth: Literal["radial", "z"]
    mod_freq_mhz: float
    driver: str  # the layout's driver, "" when every topic was named
    amplitude: str  # what the amplitude image is


def range_plane(image: np.ndarray, options: ResolvedOptions, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W) float32 radial range in metres (NaN where no return) from a range image's array."""
    if image.dtype.kind != "f" and options.range_unit == "device":
        metres = sr3000.raw_to_range_m(image, round(options.mod_freq_mhz * 1000))
    else:
        metres = depth_metres(image, 1e-3)
    return intrinsics.radial_from_z(metres).astype(np.float32) if options.depth == "z" else metres


class RosbagSource(BagSource):
    """Frames of a ROS driver's bag: each header stamp with a range image, an amplitude image and a CameraInfo.

    Frame counters count the paired frames from 0; the device timestamp is the header stamp, the host times are
    the bag's receive time of the range image; the device is backend "rosbag", model = the driver (or the
    header's frame_id when the topics were named). Messages whose stamp never completes a frame are counted in
    counters["unpaired_<role>"]. Opening checks the topics (BagError names a missing one and lists the bag's
    topics); iterating raises BagError at the first image tofd cannot use, and ends early (with `damage` set and
    the rest ledgered as one rejected frame) where the bag is damaged.
    """

    def __init__(self, path: str | Path, options: RangeOptions | None = None, bag: BagReader | None = None) -> None:
        super().__init__(path, bag)
        options = options or RangeOptions()
        options.validate()
        try:
            self.options = self._resolve(options)
        except BagError:
            self.bag.close()
            raise
        self.range_messages = self.message_count(self.options.topics["range"])
        khz = round(options.mod_freq_mhz * 1000)
        index = sr3000.mod_freq_index(khz)
        device_units = self.options.range_unit == "device"
        self._registers = Registers(mod_freq_index=index) if device_units and index is not None else None
        """An SR3000 (SwissRanger device units at one of its frequencies): its MOD_FREQ register, else None."""
        self.amplitude_kind = AMPLITUDE_KINDS.get(self.options.amplitude, "amplitude")
        self.unambiguous_range_m = sr3000.non_ambiguity_range_m(khz) if device_units else None
        self._metres_per_unit, self._invalid = ((self.unambiguous_range_m / 65535, sr3000.RAW_INVALID)
                                                if self.unambiguous_range_m else (1e-3, 0))
        self.settings = {"driver": self.options.driver, "topics": self.options.topics,
                         "range_unit": self.options.range_unit, "depth": self.options.depth,
                         "amplitude": self.options.amplitude}
        if device_units:
            self.settings["mod_freq_mhz"] = options.mod_freq_mhz

    def _resolve(self, options: RangeOptions) -> ResolvedOptions:
        """The bag's topics and encoding: the options over the detected driver's, each topic checked to be in the
        bag with its message type."""
        topics = self.bag.topics
        detected = detect_layout(topics)
        layout: Layout | None = detected[0] if detected else None
        found = detected[1] if detected else {}
        chosen: dict[str, str] = {}
        for role, topic in options.topics.items():
            name = topic or found.get(role)
            if name is None:
                if layout is None:
                    raise no_layout_error(self.path, topics)
                raise BagError(f"{self.path}: the {layout.driver} driver's bag has no {role} topic (its "
                               f"{layout.relative_topics[role] or role} under {layout.namespace or '/'}); "
                               f"name one with --{role.replace('_', '-')}-topic; the bag has: "
                               f"{describe_topics(topics)}")
            if name not in topics:
                raise BagError(f"{self.path}: no {role} topic {name}; the bag has: {describe_topics(topics)}")
            expected = (CAMERA_INFO_TYPE,) if role == "camera_info" else IMAGE_TYPES
            if topics[name].msgtype not in expected:
                raise BagError(f"{self.path}: {role} topic {name} is {topics[name].msgtype}, expected "
                               f"{' or '.join(expected)}")
            chosen[role] = name
        named = all(options.topics.values())
        return ResolvedOptions(chosen, options.range_unit or (layout.range_unit if layout else "mm"),
                               options.depth or (layout.depth if layout else "z"), options.mod_freq_mhz,
                               "" if named or layout is None else layout.driver,
                               layout.amplitude if layout and not named else "amplitude")

    def _check_calibration(self, intrinsics: Intrinsics, where: str, when: str) -> Intrinsics:
        """`intrinsics` if it is the first calibration or the same as before; BagError (naming the topic or stream
        `where` and e.g. `when` = "at stamp 1.000000000") when it changes."""
        if self.intrinsics is None:
            self.intrinsics = intrinsics
        elif intrinsics != self.intrinsics:
            raise BagError(f"{where}: the calibration changes {when} ({self.intrinsics} -> {intrinsics}); a tofd "
                           "recording holds one camera calibration")
        return intrinsics

    def _frame(self, counter: int, parts: dict[str, tuple[Any, RawMessage]]) -> Frame:
        """The Frame of one stamp's range image, amplitude image and CameraInfo."""
        topics = self.options.topics
        (rng, raw_range), (amp, _), (info, _) = parts["range"], parts["amplitude"], parts["camera_info"]
        intrinsics = self._check_calibration(camera_info_intrinsics(info, topics["camera_info"]),
                                            topics["camera_info"], f"at stamp {_seconds(info)}")
        range_image = plane(rng, self.bag.topics[topics["range"]].msgtype, RANGE_ENCODINGS, topics["range"])
        amplitude_raw = plane(amp, self.bag.topics[topics["amplitude"]].msgtype, AMPLITUDE_ENCODINGS,
                              topics["amplitude"])
        amplitude = amplitude_raw.astype(np.float32)
        self.check_sizes(f"stamp {_seconds(rng)}", range_image=range_image.shape, amplitude_image=amplitude.shape,
                         camera_info=intrinsics.shape)
        self.note_signal(range_image, amplitude_raw, self._metres_per_unit, self._invalid)
        log_ns = raw_range.log_ns
        return Frame(range_m=range_plane(range_image, self.options, intrinsics), amplitude=amplitude,
                     frame_counter=counter, timestamp_us=_stamp(rng) // 1000, host_monotonic_s=log_ns / 1e9,
                     host_wall_s=log_ns / 1e9, intrinsics=intrinsics,
                     device=DeviceInfo(serial="", backend="rosbag", model=self.options.driver or rng.header.frame_id),
                     registers=self._registers)

    def frames(self) -> Iterator[Frame]:
        """Frames in the order their last message arrives in the bag."""
        roles = {topic: role for role, topic in self.options.topics.items()}
        types = {topic: self.bag.topics[topic].msgtype for topic in roles}
        join: StreamJoin[int, tuple[Any, RawMessage]] = StreamJoin(roles.values(), self.counters)
        counter = 0
        for message in self.messages(set(roles)):
            role = roles[message.topic]
            try:
                msg = self.decode(message, types[message.topic])
            except DamagedMessage as exc:  # a garbled range image is a frame lost; another message leaves its
                self.damaged(counter if role == "range" else None, exc)  # frame's other messages unpaired
                counter += role == "range"
                continue
            parts = join.add(_stamp(msg), role, (msg, message))
            if parts is None:
                continue
            try:
                frame = self._frame(counter, parts)
            except DamagedMessage as exc:
                self.damaged(counter, exc)
            else:
                yield frame
            counter += 1
        join.finish()


def _stamp(msg: Any) -> int:
    """A message's header stamp in nanoseconds."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _seconds(msg: Any) -> str:
    """A message's header stamp as ROS prints it, e.g. "1700000000.033333000" (seconds)."""
    return f"{msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}"
