"""An Orbbec SDK v2 recording as the SDK's rosbag writer lays it out (its OrbbecSDK_v2 src/media/ros sources and
3rdparty/rosbag message headers), written with rosbags' ROS 1 writer: the connections carry the SDK's message
definitions (its Image definition without depth_units, md5 of the standard Image), the bytes follow the SDK's
serializers (depth_units and the frame number/timestamps after Image.data; OBProperty's id as uint32); the
stream profiles are written when recording stops, after the frames."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer

IMAGE_MD5 = "060021388200f6f0f447d0fcd9c64743"
PLACEHOLDER_MD5 = "0123456789abcdef0123456789abcdef"  # what the SDK declares for its custom messages
HEADER_DEF = "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
SEP = "=" * 80 + "\n"
IMAGE_DEF = ("Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n"
             "uint8[] data\nuint64 number\nuint64 timestamp_usec\nuint64 timestamp_systemusec\n"
             "uint64 timestamp_globalusec\nuint8[] metadata\nuint32 metadatasize\n" + SEP + HEADER_DEF)
PROFILE_DEF = ("std_msgs/Header header\nuint8 streamType\nuint8 format\nfloat32[9] rotationMatrix\n"
               "float32[3] translationMatrix\nuint16 width\nuint16 height\nuint16 fps\nfloat32[4] cameraIntrinsic\n"
               "float32[8] cameraDistortion\nuint8 distortionModel\n")
DEVICE_DEF = ("std_msgs/Header header\nstring name\nstring fullName\nstring asicName\nuint16 vid\nuint16 pid\n"
              "string uid\nstring sn\nstring fwVersion\nstring hwVersion\nstring supportedSdkVersion\n"
              "string connectionType\nuint16 type\nuint8 backendType\nstring ipAddress\nstring localMac\n")
PROPERTY_DEF = "std_msgs/Header header\nuint8 propertyId\nuint8[] data  \nuint32 datasize\n"
FORMAT_Y16 = 8  # OB_FORMAT_Y16
BROWN_CONRADY_K6 = 4  # OB_DISTORTION_BROWN_CONRADY_K6


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _header(stamp_us: int, seq: int = 0) -> bytes:
    return struct.pack("<III", seq, stamp_us // 1_000_000, stamp_us % 1_000_000 * 1000) + _string("")


def image_bytes(plane: np.ndarray, number: int, stamp_us: int, depth_units: float = 0.0) -> bytes:
    h, w = plane.shape
    data = np.ascontiguousarray(plane.astype("<u2")).tobytes()
    return (_header(stamp_us) + struct.pack("<II", h, w) + _string("mono16") + struct.pack("<BI", 0, w * 2)
            + struct.pack("<I", len(data)) + data + struct.pack("<fQQQQ", depth_units, number, stamp_us, stamp_us, 0)
            + struct.pack("<I", 0) + struct.pack("<I", 0))


def profile_bytes(stream_type: int, intrinsics: tuple[float, float, float, float], size: tuple[int, int],
                  distortion: tuple[float, ...], model: int, stamp_us: int, fps: int = 30) -> bytes:
    return (_header(stamp_us) + struct.pack("<BB", stream_type, FORMAT_Y16) + struct.pack("<12f", *[0.0] * 12)
            + struct.pack("<HHH", size[0], size[1], fps) + struct.pack("<4f", *intrinsics)
            + struct.pack("<8f", *distortion) + struct.pack("<B", model))


def device_bytes(name: str, serial: str, firmware: str, stamp_us: int) -> bytes:
    return (_header(stamp_us) + _string(name) + _string(name) + _string("MX6600") + struct.pack("<HH", 0x2BC5, 0x066B)
            + _string("1-2") + _string(serial) + _string(firmware) + _string("0.1") + _string("2.0.0")
            + _string("USB3.1") + struct.pack("<HB", 1, 0) + _string("") + _string(""))


def property_bytes(property_id: int, value: bytes, stamp_us: int) -> bytes:
    return _header(stamp_us) + struct.pack("<I", property_id) + _string_bytes(value) + struct.pack("<I", len(value))


def _string_bytes(value: bytes) -> bytes:
    return struct.pack("<I", len(value)) + value


def write_orbbec_bag(path: Path, depth: list[np.ndarray], infrared: list[np.ndarray], k: tuple[float, float, float,
                     float], distortion_sdk_order: tuple[float, ...], model: int = BROWN_CONRADY_K6,
                     properties: dict[int, bytes] | None = None, lz4: bool = True, first_number: int = 7,
                     profiles: bool = True) -> Path:
    """An Orbbec SDK v2 .bag of depth (Y16) and IR (Y16) frames at 30 fps from device time 5 s, intrinsics
    [fx, fy, cx, cy], distortion [k1..k6, p1, p2] of `model`, the given properties (id -> value bytes)."""
    writer = Writer(path)
    if lz4:
        writer.set_compression(Writer.CompressionFormat.LZ4)
    h, w = depth[0].shape
    t0 = 5_000_000
    with writer:
        def connection(topic: str, msgtype: str, msgdef: str, md5: str):  # noqa: ANN202
            return writer.add_connection(topic, msgtype, msgdef=msgdef, md5sum=md5)

        dev = connection("/cam/deviceInfo", "custom_msg/msg/DeviceInfo", DEVICE_DEF, PLACEHOLDER_MD5)
        writer.write(dev, t0 * 1000, device_bytes("Femto Bolt", "CL8F12300AB", "1.0.9", t0))
        prop = connection("/cam/property", "custom_msg/msg/property", PROPERTY_DEF, PLACEHOLDER_MD5)
        for pid, value in (properties or {}).items():
            writer.write(prop, t0 * 1000, property_bytes(pid, value, t0))
        depth_c = connection("/cam/sensor_3/frameType_3", "sensor_msgs/msg/Image", IMAGE_DEF, IMAGE_MD5)
        ir_c = connection("/cam/sensor_1/frameType_1", "sensor_msgs/msg/Image", IMAGE_DEF, IMAGE_MD5)
        for n, (d, ir) in enumerate(zip(depth, infrared, strict=True)):
            stamp = t0 + round(n * 1e6 / 30)
            writer.write(depth_c, stamp * 1000, image_bytes(d, first_number + n, stamp))
            writer.write(ir_c, stamp * 1000 + 1000, image_bytes(ir, first_number + n, stamp))
        if profiles:
            for stream, topic in ((3, "/cam/streamProfileType_3"), (1, "/cam/streamProfileType_1")):
                c = connection(topic, "custom_msg/msg/OBStreamProfileInfo", PROFILE_DEF, PLACEHOLDER_MD5)
                writer.write(c, t0 * 1000, profile_bytes(stream, k, (w, h), distortion_sdk_order, model, t0))
    return path
