"""ROS bags written with rosbags' own writers (ROS 1 .bag, ROS 2 sqlite3 and MCAP) from tofd Frames, for the import
tests: the messages a SwissRanger-like driver publishes for each frame."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from tofd.drivers import sr3000
from tofd.drivers.bags.driver_bag import CAMERA_INFO_TYPE, IMAGE_TYPE
from tofd.drivers.bags.driver_layouts import LAYOUTS
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics

BagKind = Literal["ros1", "sqlite3", "mcap"]
BAG_KINDS: tuple[BagKind, ...] = ("ros1", "sqlite3", "mcap")
TOPICS: dict[str, str] = LAYOUTS[0].topics  # type: ignore[assignment]  (the SwissRanger driver's)


def typestore(kind: BagKind) -> Any:
    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


def bag_path(directory: Path, kind: BagKind, name: str = "clip") -> Path:
    """Where a bag of `kind` goes: a .bag file for ROS 1, a bag directory for ROS 2."""
    return directory / (f"{name}.bag" if kind == "ros1" else name)


def _header(ts: Any, stamp_ns: int, seq: int, frame_id: str = "SwissRanger") -> Any:
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    fields = {"stamp": stamp, "frame_id": frame_id}
    return Header(seq=seq, **fields) if "seq" in Header.__dataclass_fields__ else Header(**fields)


def image(ts: Any, plane: np.ndarray, encoding: str, stamp_ns: int, seq: int = 0, big_endian: bool = False,
          row_padding: int = 0, frame_id: str = "SwissRanger") -> Any:
    """A sensor_msgs/Image of an (H, W) array: its dtype's bytes in the given byte order, each row followed by
    `row_padding` bytes."""
    h, w = plane.shape
    rows = plane.astype(plane.dtype.newbyteorder(">" if big_endian else "<")).view(np.uint8).reshape(h, -1)
    data = np.concatenate([rows, np.full((h, row_padding), 0xAB, np.uint8)], axis=1)
    return ts.types[IMAGE_TYPE](header=_header(ts, stamp_ns, seq, frame_id), height=h, width=w, encoding=encoding,
                                is_bigendian=int(big_endian), step=data.shape[1], data=data.ravel())


def compressed_depth(ts: Any, depth_mm: np.ndarray, stamp_ns: int, frame_id: str = "camera") -> Any:
    """A sensor_msgs/CompressedImage as image_transport's compressedDepth plugin writes 16UC1 depth: format
    "16UC1; compressedDepth png", data = its 12-byte configuration header (format 0, no quantisation) + a PNG."""
    ok, png = cv2.imencode(".png", depth_mm)
    assert ok
    data = np.concatenate([np.zeros(12, np.uint8), png.ravel()])
    return ts.types["sensor_msgs/msg/CompressedImage"](header=_header(ts, stamp_ns, 0, frame_id),
                                                       format="16UC1; compressedDepth png", data=data)


def lens_camera_info(ts: Any, i: Intrinsics, stamp_ns: int, seq: int = 0, frame_id: str = "SwissRanger") -> Any:
    """A sensor_msgs/CameraInfo of intrinsics with their lens (a pinhole as plumb_bob with zero D; ROS 1 names
    its matrices K, D, R, P; ROS 2 k, d, r, p)."""
    k = np.array([i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1], np.float64)
    p = np.array([i.fx, 0, i.cx, 0, 0, i.fy, i.cy, 0, 0, 0, 1, 0], np.float64)
    cls = ts.types[CAMERA_INFO_TYPE]
    upper = "K" in cls.__dataclass_fields__
    pinhole = i.distortion_model == "none"
    d = np.zeros(5) if pinhole else np.array(i.distortion, np.float64)
    mats = {"d": d, "k": k, "r": np.eye(3).ravel(), "p": p}
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return cls(header=_header(ts, stamp_ns, seq, frame_id), height=i.height, width=i.width,
               distortion_model="plumb_bob" if pinhole else i.distortion_model, binning_x=0, binning_y=0, roi=roi,
               **{(n.upper() if upper else n): m for n, m in mats.items()})


def camera_info(ts: Any, frame: Frame, stamp_ns: int, seq: int = 0, distortion: float = 0.0) -> Any:
    """A plumb_bob sensor_msgs/CameraInfo of the frame's intrinsics, with k1 = `distortion`."""
    i = frame.intrinsics
    if distortion:
        i = dataclasses.replace(i, distortion_model="plumb_bob", distortion=(distortion, 0, 0, 0, 0))
    return lens_camera_info(ts, i, stamp_ns, seq)


def range_image(frame: Frame, encoding: str, unit: str = "device", depth: str = "radial") -> np.ndarray:
    """The frame's range as a driver would publish it: 32FC1 metres, 16UC1 device units (SwissRanger, at the
    frame's modulation frequency) or millimetres (0 = no return); z-depth along the optical axis or radial."""
    metres = frame.range_m
    if depth == "z":
        metres = (metres * frame.intrinsics.unit_rays()[..., 2]).astype(np.float32)
    if encoding == "32FC1":
        return metres
    if unit == "device":
        return sr3000.range_m_to_raw(metres, sr3000.mod_freq_khz(frame.registers.mod_freq_index))
    mm = np.rint(np.nan_to_num(metres, nan=0.0, posinf=0.0, neginf=0.0) * 1000.0)
    return np.clip(mm, 0, 65535).astype(np.uint16)


def frame_messages(ts: Any, frame: Frame, encoding: str = "16UC1", unit: str = "device",
                   depth: str = "radial") -> list[tuple[str, Any]]:
    """(topic, message) of one frame on the default topics, stamped with its device timestamp."""
    stamp = frame.timestamp_us * 1000
    amplitude = frame.amplitude.astype(np.uint16) if encoding != "32FC1" else frame.amplitude
    return [(TOPICS["range"], image(ts, range_image(frame, encoding, unit, depth), encoding, stamp)),
            (TOPICS["amplitude"], image(ts, amplitude, encoding, stamp)),
            (TOPICS["camera_info"], camera_info(ts, frame, stamp))]


def write_bag(path: Path, kind: BagKind, messages: Iterable[tuple[str, Any]], chunk_bytes: int | None = None,
              compression: str | None = None) -> Path:
    """A bag of `kind` with these (topic, message) in order, each received 1 ms after the one before (ROS 1:
    chunks of about `chunk_bytes`, default rosbags', compressed with `compression` "bz2" or "lz4")."""
    ts = typestore(kind)
    writer = Writer1(path) if kind == "ros1" else Writer2(
        path, version=9, storage_plugin=StoragePlugin.SQLITE3 if kind == "sqlite3" else StoragePlugin.MCAP)
    if chunk_bytes is not None and isinstance(writer, Writer1):
        writer.chunk_threshold = chunk_bytes
    if compression is not None and isinstance(writer, Writer1):
        writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    serialize = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr
    connections: dict[str, Any] = {}
    with writer:
        for n, (topic, msg) in enumerate(messages):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            writer.write(connections[topic], 1_700_000_000_000_000_000 + n * 1_000_000,
                         serialize(msg, msg.__msgtype__))
    return path


def write_frames_bag(directory: Path, kind: BagKind, frames: list[Frame], **kwargs: str) -> Path:
    """A bag of `kind` with frame_messages of every frame."""
    ts = typestore(kind)
    return write_bag(bag_path(directory, kind), kind, (m for f in frames for m in frame_messages(ts, f, **kwargs)))
