"""Orbbec SDK v2 recordings (ob::RecordDevice, OrbbecViewer's record button) as a frame source.

A ROS 1 bag (chunks uncompressed or LZ4) written by the SDK's own rosbag writer:
- /cam/sensor_<OBSensorType>/frameType_<OBFrameType>: sensor_msgs/Image whose bytes continue after `data` with
  float32 depth_units, uint64 number, timestamp_usec, timestamp_systemusec, timestamp_globalusec, uint8[] metadata
  and uint32 metadatasize; the definition stored in the bag omits depth_units, so they are read by layout
  (tofd.drivers.bags.ros1_wire). Depth: sensor 3 (Z16 / Y16), infrared: sensor 1 (or the left IR, 6).
- /cam/streamProfileType_<OBStreamType>: custom_msg/OBStreamProfileInfo, written when recording stops: size,
  fps, intrinsics [fx, fy, cx, cy], distortion [k1..k6, p1, p2] and its OBCameraDistortionModel.
- /cam/deviceInfo (custom_msg/OBDeviceInfo: name, serial, firmware) and /cam/property (custom_msg/OBProperty,
  whose propertyId is written as uint32 although declared uint8): the depth unit, when not 1 mm, is property 176
  (OB_PROP_DEPTH_UNIT_FLEXIBLE_ADJUSTMENT_FLOAT, mm) or 75 (OB_PROP_DEPTH_PRECISION_LEVEL_INT).
Depth is z-depth (0 = no return) in depth units (Image.depth_units when written, else the property, else 1 mm as
the Femto ToF cameras deliver); it becomes radial range through the undistorted rays. Frames pair depth and
infrared by device frame number; counters and timestamps are the device's. Frames carry no SR3000 registers but
a SensorInfo: depth unit, infrared amplitude, the stream profile's fps and the recorded properties as settings.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tofd.drivers.bags import ros1_wire
from tofd.drivers.bags.camera_info import orbbec_lens_intrinsics
from tofd.drivers.bags.images import AMPLITUDE_ENCODINGS, RANGE_ENCODINGS, image_plane
from tofd.drivers.bags.join import StreamJoin
from tofd.drivers.bags.scan import BagError, BagReader, DamagedMessage, RawMessage, Topic
from tofd.drivers.bags.source import BagSource
from tofd.drivers.depth import depth_metres
from tofd.drivers.frame import COUNTER_LIMIT, DeviceInfo, Frame
from tofd.drivers.intrinsics import Intrinsics

FRAME_TOPIC = re.compile(r"^/cam/sensor_(\d+)/frameType_(\d+)$")
DEPTH_SENSOR = 3  # OB_SENSOR_DEPTH
IR_SENSORS = (1, 6)  # OB_SENSOR_IR, OB_SENSOR_IR_LEFT
DEPTH_STREAM = 3  # OB_STREAM_DEPTH
DEVICE_TOPIC, PROPERTY_TOPIC = "/cam/deviceInfo", "/cam/property"
PROPERTY_DEPTH_UNIT_MM = 176  # OB_PROP_DEPTH_UNIT_FLEXIBLE_ADJUSTMENT_FLOAT
PROPERTY_PRECISION_LEVEL = 75  # OB_PROP_DEPTH_PRECISION_LEVEL_INT
PRECISION_LEVEL_MM = (1.0, 0.8, 0.4, 0.1, 0.2, 0.5, 0.05)
"""OBDepthPrecisionLevel -> millimetres per depth unit."""


def is_orbbec(topics: dict[str, Topic]) -> bool:
    """Whether a bag's topics are an Orbbec SDK recording with a depth stream."""
    return any((m := FRAME_TOPIC.match(t)) is not None and int(m.group(1)) == DEPTH_SENSOR for t in topics)


class OrbbecSource(BagSource):
    """Frames of an Orbbec SDK v2 recording: depth + infrared, paired by device frame number.

    The device is backend "orbbec", model, serial and firmware from /cam/deviceInfo. Depth frames without their
    infrared frame are counted in counters["unpaired_range"], infrared ones in counters["unpaired_amplitude"].
    """

    def __init__(self, path: str | Path, bag: BagReader | None = None) -> None:
        super().__init__(path, bag)
        try:
            self.depth_topic, self.ir_topic = self._topics()
            self.intrinsics = self._calibration()  # the depth stream's profile, known before the first frame
            self.device, units_mm, properties = self._device_and_units()
        except BagError:
            self.bag.close()
            raise
        self._units_mm = units_mm
        self.range_messages = self.message_count(self.depth_topic)
        self.settings |= {"format": "Orbbec SDK v2 .bag", "depth_topic": self.depth_topic,
                         "infrared_topic": self.ir_topic, "depth_unit_property_mm": units_mm,
                         "amplitude": "infrared", "properties": properties}

    def _topics(self) -> tuple[str, str]:
        frames = {int(m.group(1)): t for t in self.bag.topics if (m := FRAME_TOPIC.match(t))}
        if DEPTH_SENSOR not in frames:
            raise BagError(f"{self.path}: an Orbbec recording without a depth stream")
        ir = next((frames[s] for s in IR_SENSORS if s in frames), None)
        if ir is None:
            raise BagError(f"{self.path}: the Orbbec recording has no infrared stream: tofd needs one as amplitude "
                           "(record the IR stream with the depth stream)")
        return frames[DEPTH_SENSOR], ir

    def _calibration(self) -> Intrinsics:
        topic = f"/cam/streamProfileType_{DEPTH_STREAM}"
        if topic not in self.bag.topics:
            have = ", ".join(sorted(self.bag.topics))
            raise BagError(f"{self.path}: no {topic} (the depth stream's intrinsics, written when recording stops: "
                           f"a recording cut short has none); the bag has: {have}")
        for message in self.bag.messages({topic}):
            try:
                profile = ros1_wire.ob_stream_profile(message.raw)
            except ros1_wire.WireError as exc:
                raise BagError(f"{self.path}: {topic}: unreadable stream profile ({exc})") from None
            self.settings["fps"] = profile.fps
            return orbbec_lens_intrinsics(profile.width, profile.height, profile.intrinsic, profile.distortion_model,
                                          profile.distortion, f"{self.path}: {topic}")
        raise BagError(f"{self.path}: {topic} has no message")

    def _device_and_units(self) -> tuple[DeviceInfo, float | None, dict[str, str]]:
        """The device, the depth unit property in mm (None: not recorded) and every recorded property as hex."""
        device = DeviceInfo(serial="", backend="orbbec", model="Orbbec")
        units: float | None = None
        properties: dict[str, str] = {}
        for message in self.bag.messages({DEVICE_TOPIC, PROPERTY_TOPIC}):
            try:
                if message.topic == DEVICE_TOPIC:
                    info = ros1_wire.ob_device_info(message.raw)
                    device = DeviceInfo(serial=info.serial, firmware=info.firmware, backend="orbbec",
                                        model=info.name or f"Orbbec {info.vid:04x}:{info.pid:04x}")
                    continue
                prop = ros1_wire.ob_property(message.raw)
            except ros1_wire.WireError as exc:
                raise BagError(f"{self.path}: {message.topic}: unreadable message ({exc})") from None
            properties[str(prop.property_id)] = prop.data.hex()
            if prop.property_id == PROPERTY_DEPTH_UNIT_MM and len(prop.data) >= 4:
                units = float(struct.unpack("<f", prop.data[:4])[0])
            elif prop.property_id == PROPERTY_PRECISION_LEVEL and len(prop.data) >= 4 and units is None:
                level = struct.unpack("<i", prop.data[:4])[0]
                units = PRECISION_LEVEL_MM[level] if 0 <= level < len(PRECISION_LEVEL_MM) else None
        return device, units, properties

    def _image(self, message: RawMessage) -> ros1_wire.ExtendedImage:
        try:
            return ros1_wire.extended_image(message.raw)
        except ros1_wire.WireError as exc:
            raise DamagedMessage(f"{self.path}: {message.topic}: unreadable image ({exc})") from None

    def frames(self) -> Iterator[Frame]:
        """Frames in the order their second image arrives."""
        roles = {self.depth_topic: "range", self.ir_topic: "amplitude"}
        join: StreamJoin[int, tuple[ros1_wire.ExtendedImage, RawMessage]] = StreamJoin(roles.values(), self.counters)
        for message in self.messages(set(roles)):
            try:
                image = self._image(message)
            except DamagedMessage as exc:
                self.damaged(None, exc)
                continue
            number = image.number if image.number is not None else image.header.seq
            parts = join.add(number, roles[message.topic], (image, message))
            if parts is None:
                continue
            try:
                frame = self._frame(number, parts["range"], parts["amplitude"])
            except DamagedMessage as exc:
                self.damaged(number, exc)
                continue
            yield frame
        join.finish()

    def _frame(self, number: int, depth: tuple[ros1_wire.ExtendedImage, RawMessage],
               infrared: tuple[ros1_wire.ExtendedImage, RawMessage]) -> Frame:
        (image, message), (ir_image, _) = depth, infrared
        intrinsics = self.intrinsics
        assert intrinsics is not None
        raw = image_plane(image, RANGE_ENCODINGS, self.depth_topic)
        ir_raw = image_plane(ir_image, AMPLITUDE_ENCODINGS, self.ir_topic)
        amplitude = ir_raw.astype(np.float32)
        self.check_sizes(f"{self.path}: frame {number}", depth_image=raw.shape, infrared_image=amplitude.shape,
                         stream_profile=intrinsics.shape)
        units_mm = image.depth_units or self._units_mm or 1.0
        self.settings.setdefault("depth_units_mm", units_mm)
        self.note_signal(raw, ir_raw, units_mm * 1e-3)
        z = depth_metres(raw, units_mm * 1e-3)
        timestamp_us = image.timestamp_usec if image.timestamp_usec is not None else image.header.stamp_ns // 1000
        return Frame(range_m=intrinsics.radial_from_z(z).astype(np.float32), amplitude=amplitude,
                     frame_counter=number % COUNTER_LIMIT, timestamp_us=timestamp_us,
                     host_monotonic_s=message.log_ns / 1e9, host_wall_s=message.log_ns / 1e9,
                     intrinsics=intrinsics, device=self.device)

