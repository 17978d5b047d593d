"""RealSense SDK recordings (rs2::recorder, the RealSense Viewer's record button) as a frame source.

Two layouts, both under /device_<d>/sensor_<s>/<Stream>_<index>/ with a /file_version topic:
- librealsense >= 2.57: a ROS 2 sqlite3 bag (.db3). Depth is sensor_msgs/CompressedImage
  "16UC1; compressedDepth png" on image/data/compressedDepth, infrared "mono8; png compressed mono8" (or mono16)
  on image/data/compressed; each frame's image/metadata is a std_msgs/String "Frame number=..;timestamp=..;
  depth_units=..;" written with the same bag time as its image; the stream's camera_info is a String
  "width=..;fx=..;ppx=..;model=Brown Conrady;coeffs=.." (and a sensor_msgs/CameraInfo every frame).
- librealsense <= 2.56: a ROS 1 bag (.bag). Images are sensor_msgs/Image carrying an undeclared float32 depth
  unit (metres) after their data (tofd.drivers.bags.ros1_wire), header.seq = frame number, header.stamp = device
  timestamp; info/camera_info is a sensor_msgs/CameraInfo (once) whose distortion_model is librealsense's name;
  the sensor's Depth_Units option is on option/Depth_Units/value.
Depth is z-depth in depth units (0 = no return); it becomes radial range through the undistorted rays. The
amplitude is the infrared image of the same sensor (the first Infrared stream), paired by frame number. Frames
carry no SR3000 registers but a SensorInfo: depth unit, infrared amplitude, stream infos and options as settings.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tofd.drivers.bags import ros1_wire
from tofd.drivers.bags.camera_info import camera_info_intrinsics, lens_intrinsics
from tofd.drivers.bags.images import AMPLITUDE_ENCODINGS, IMAGE_TYPES, RANGE_ENCODINGS, plane
from tofd.drivers.bags.join import StreamJoin
from tofd.drivers.bags.scan import BagError, BagReader, DamagedMessage, RawMessage, Topic
from tofd.drivers.bags.source import BagSource
from tofd.drivers.depth import depth_metres
from tofd.drivers.frame import COUNTER_LIMIT, DeviceInfo, Frame
from tofd.drivers.intrinsics import Intrinsics

STREAM_TOPIC = re.compile(r"^(/device_\d+/sensor_\d+/)(Depth|Infrared)_(\d+)/image/data(/compressed\w*)?$")
"""A stream's image topic: sensor prefix, stream name, index, transport."""


def is_realsense(topics: dict[str, Topic]) -> bool:
    """Whether a bag's topics are a RealSense SDK recording with a depth stream."""
    return "/file_version" in topics and any(
        (m := STREAM_TOPIC.match(t)) is not None and m.group(2) == "Depth" for t in topics)


@dataclass(frozen=True, slots=True)
class _Stream:
    image_topic: str
    base: str  # /device_0/sensor_0/Depth_0


@dataclass(slots=True)
class _Image:
    """One decoded stream image: device frame number and timestamp, the array, its depth unit (0: none said)."""

    number: int
    timestamp_us: int
    array: np.ndarray
    units_m: float
    log_ns: int


class RealSenseSource(BagSource):
    """Frames of a RealSense SDK recording: depth + infrared of one sensor, paired by device frame number.

    Frame counters and timestamps are the device's (metadata "Frame number" and "timestamp", or the legacy
    header's seq and stamp); the host times the bag's receive time of the depth image; the device is backend
    "realsense", model and serial from /device_0/info. Depth frames without their infrared frame are counted in
    counters["unpaired_range"], infrared ones in counters["unpaired_amplitude"].
    """

    def __init__(self, path: str | Path, bag: BagReader | None = None) -> None:
        super().__init__(path, bag)
        try:
            self.depth, self.infrared = self._streams()
            self.intrinsics = self._calibration()  # one per stream, known before the first frame
            self._option_units = self._depth_units_option()
            self.device = self._device()
        except BagError:
            self.bag.close()
            raise
        self.range_messages = self.message_count(self.depth.image_topic)
        self.settings = {"format": "RealSense SDK " + ("ROS 1 .bag (librealsense <= 2.56)" if self.bag.ros1 else
                                                         "ROS 2 .db3 (librealsense >= 2.57)"),
                         "depth_topic": self.depth.image_topic, "infrared_topic": self.infrared.image_topic,
                         "depth_units_option_m": self._option_units, "amplitude": "infrared", **self._infos()}

    def _streams(self) -> tuple[_Stream, _Stream]:
        found: dict[str, list[tuple[str, int, str]]] = {"Depth": [], "Infrared": []}
        for topic in self.bag.topics:
            if (m := STREAM_TOPIC.match(topic)) and self.bag.topics[topic].msgtype in IMAGE_TYPES:
                found[m.group(2)].append((m.group(1), int(m.group(3)), topic))
        if not found["Depth"]:
            raise BagError(f"{self.path}: a RealSense recording without a depth stream")
        sensor, index, depth_topic = sorted(found["Depth"])[0]
        same_sensor = sorted(f for f in found["Infrared"] if f[0] == sensor)
        if not same_sensor:
            raise BagError(f"{self.path}: the RealSense recording has no infrared stream of the depth sensor "
                           f"{sensor}: tofd needs one as amplitude (record Depth and Infrared 1 together)")
        _, ir_index, ir_topic = same_sensor[0]
        return (_Stream(depth_topic, f"{sensor}Depth_{index}"), _Stream(ir_topic, f"{sensor}Infrared_{ir_index}"))

    def _first(self, topic: str) -> Any | None:
        """The first message of `topic` decoded, or None when the bag has none."""
        if topic not in self.bag.topics:
            return None
        for message in self.bag.messages({topic}):
            return self.decode(message, self.bag.topics[topic].msgtype)
        return None

    def _all(self, topics: set[str]) -> Iterator[tuple[str, Any]]:
        present = {t for t in topics if t in self.bag.topics}
        for message in self.bag.messages(present) if present else ():
            yield message.topic, self.decode(message, self.bag.topics[message.topic].msgtype)

    def _calibration(self) -> Intrinsics:
        """The depth stream's intrinsics with librealsense's lens model."""
        where = f"{self.path}: {self.depth.base}"
        if self.bag.ros1:
            info = self._first(f"{self.depth.base}/info/camera_info")
            if info is None:
                raise BagError(f"{where}: no info/camera_info (the stream's calibration)")
            return camera_info_intrinsics(info, f"{where}/info/camera_info")
        text = self._first(f"{self.depth.base}/camera_info")
        if text is None:
            info = self._first(f"{self.depth.base}/image/camera_info")
            if info is None:
                raise BagError(f"{where}: no camera_info (the stream's calibration)")
            return camera_info_intrinsics(info, f"{where}/image/camera_info")
        fields = _key_values(text.data, ";")
        try:
            k = tuple(float(fields[name]) for name in ("fx", "fy", "ppx", "ppy"))
            coefficients = [float(c) for c in fields.get("coeffs", "").split(",") if c.strip()]
            return lens_intrinsics(int(fields["width"]), int(fields["height"]), k,  # type: ignore[arg-type]
                                   fields.get("model"), coefficients, f"{where}/camera_info")
        except (KeyError, ValueError) as exc:
            raise BagError(f"{where}/camera_info: unreadable calibration {text.data!r} ({exc})") from None

    def _depth_units_option(self) -> float | None:
        """The depth sensor's Depth_Units option in metres, if recorded."""
        sensor = self.depth.base.rsplit("/", 1)[0]
        msg = self._first(f"{sensor}/option/Depth_Units/value")
        if msg is None:
            return None
        try:
            return float(msg.data)
        except ValueError:
            raise BagError(f"{self.path}: {sensor}/option/Depth_Units/value is {msg.data!r}, not a number") from None

    def _device(self) -> DeviceInfo:
        info: dict[str, str] = {}
        for _, msg in self._all({"/device_0/info"}):
            if hasattr(msg, "key"):
                info[msg.key] = msg.value
            else:
                info.update(_key_values(msg.data, ";"))
        return DeviceInfo(serial=info.get("Serial Number", ""), firmware=info.get("Firmware Version", ""),
                          backend="realsense", model=info.get("Name", "RealSense"))

    def _infos(self) -> dict[str, str]:
        """Stream settings as recorded: encoding and fps of the two streams."""
        out: dict[str, str] = {}
        for stream, name in ((self.depth, "depth"), (self.infrared, "infrared")):
            msg = self._first(f"{stream.base}/info")
            if msg is not None:
                out[f"{name}_stream"] = (msg.data if hasattr(msg, "data") and isinstance(msg.data, str)
                                         else f"encoding={msg.encoding};fps={msg.fps}")
        return out

    def _images(self) -> Iterator[tuple[str, _Image]]:
        """("range" | "amplitude", image) in bag order: depth and infrared images (a ROS 2 bag's each paired with
        its metadata by receive time; one left without the other is counted in counters["unpaired_image"] or
        counters["unpaired_metadata"])."""
        roles = {self.depth.image_topic: "range", self.infrared.image_topic: "amplitude"}
        if self.bag.ros1:
            for message in self.messages(set(roles)):
                try:
                    yield roles[message.topic], self._legacy_image(message)
                except DamagedMessage as exc:
                    self.damaged(exc.frame_number if roles[message.topic] == "range" else None, exc)
            return
        metadata = {f"{stream.base}/image/metadata": role for role, stream in
                    (("range", self.depth), ("amplitude", self.infrared))}
        join: StreamJoin[tuple[str, int], RawMessage] = StreamJoin(("image", "metadata"), self.counters)
        for message in self.messages(set(roles) | set(metadata)):
            role = roles.get(message.topic) or metadata[message.topic]
            entry = join.add((role, message.log_ns), "image" if message.topic in roles else "metadata", message)
            if entry is None:
                continue
            try:
                image = self._ros2_image(entry["image"], entry["metadata"])
            except DamagedMessage as exc:
                self.damaged(exc.frame_number if role == "range" else None, exc)
                continue
            yield role, image
        join.finish()

    def _legacy_image(self, message: RawMessage) -> _Image:
        try:
            msg = ros1_wire.extended_image(message.raw)
        except ros1_wire.WireError as exc:
            raise DamagedMessage(f"{self.path}: {message.topic}: unreadable image ({exc})") from None
        encodings = RANGE_ENCODINGS if message.topic == self.depth.image_topic else AMPLITUDE_ENCODINGS
        try:
            array = plane(msg, "sensor_msgs/msg/Image", encodings, message.topic)
        except DamagedMessage as exc:
            raise DamagedMessage(str(exc), msg.header.seq) from None
        return _Image(msg.header.seq, msg.header.stamp_ns // 1000, array, msg.depth_units, message.log_ns)

    def _ros2_image(self, message: RawMessage, metadata: RawMessage) -> _Image:
        fields = _key_values(self.decode(metadata, "std_msgs/msg/String").data, ";")
        try:
            number, timestamp_ms = int(fields["Frame number"]), float(fields["timestamp"])
        except (KeyError, ValueError):
            raise DamagedMessage(f"{self.path}: {metadata.topic}: no frame number and timestamp in "
                                 f"{fields!r}") from None
        msgtype = self.bag.topics[message.topic].msgtype
        encodings = RANGE_ENCODINGS if message.topic == self.depth.image_topic else AMPLITUDE_ENCODINGS
        try:
            array = plane(self.decode(message, msgtype), msgtype, encodings, message.topic)
        except DamagedMessage as exc:
            raise DamagedMessage(str(exc), number) from None
        return _Image(number, round(timestamp_ms * 1000), array, float(fields.get("depth_units", 0) or 0),
                      message.log_ns)

    def _units(self, depth: _Image) -> float:
        units = depth.units_m or self._option_units
        if not units or not np.isfinite(units) or units <= 0:
            raise BagError(f"{self.path}: {self.depth.image_topic}: frame {depth.number} has no depth unit (none in "
                           "the frame, no Depth_Units option)")
        return float(units)

    def frames(self) -> Iterator[Frame]:
        """Frames in the order their second image arrives."""
        join: StreamJoin[int, _Image] = StreamJoin(("range", "amplitude"), self.counters)
        for role, image in self._images():
            parts = join.add(image.number, role, image)
            if parts is not None:
                yield self._frame(parts["range"], parts["amplitude"])
        join.finish()

    def _frame(self, depth: _Image, infrared: _Image) -> Frame:
        intrinsics = self.intrinsics
        assert intrinsics is not None
        amplitude = infrared.array.astype(np.float32)
        self.check_sizes(f"{self.path}: frame {depth.number}", depth_image=depth.array.shape,
                         infrared_image=amplitude.shape, calibration=intrinsics.shape)
        units = self._units(depth)
        self.settings.setdefault("depth_units_m", units)
        self.note_signal(depth.array, infrared.array, units)
        z = depth_metres(depth.array, units)
        return Frame(range_m=intrinsics.radial_from_z(z).astype(np.float32), amplitude=amplitude,
                     frame_counter=depth.number % COUNTER_LIMIT, timestamp_us=max(0, depth.timestamp_us),
                     host_monotonic_s=depth.log_ns / 1e9, host_wall_s=depth.log_ns / 1e9, intrinsics=intrinsics,
                     device=self.device)


def _key_values(text: str, separator: str) -> dict[str, str]:
    """{"Frame number": "10", ...} of librealsense's "key=value;key=value;" strings."""
    pairs = (item.partition("=") for item in str(text).split(separator) if "=" in item)
    return {key.strip(): value.strip() for key, _, value in pairs}
