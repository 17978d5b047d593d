"""Pixel arrays of ROS image messages: sensor_msgs/Image (and its vendor-extended ROS 1 form) and
sensor_msgs/CompressedImage as image_transport's compressed and compressedDepth plugins write it.

compressedDepth (what librealsense 2.59 records depth as): `format` "16UC1; compressedDepth png" (or "32FC1; ...")
and `data` = a 12-byte configuration header (int32 format, float32 depthQuantA, depthQuantB) followed by a PNG.
16UC1: the PNG holds the uint16 values themselves. 32FC1: it holds quantised inverse depth, z = A / (v - B) metres,
0 = no return. compressed: `format` "mono16; png compressed mono16" (or jpeg), the image file as it is.
"""

from __future__ import annotations

import struct
from typing import Any

import cv2
import numpy as np

from tofd.drivers.bags.scan import BagError, DamagedMessage
from tofd.drivers.limits import image_size_problem

RANGE_ENCODINGS: dict[str, str] = {"32FC1": "f4", "16UC1": "u2", "mono16": "u2"}
"""Range image encoding -> numpy dtype (byte order from the message's is_bigendian)."""
AMPLITUDE_ENCODINGS: dict[str, str] = {**RANGE_ENCODINGS, "mono8": "u1", "8UC1": "u1"}
"""Amplitude image encoding -> numpy dtype."""
EXTRA_ENCODINGS: dict[str, str] = {"Z16": "u2", "Y16": "u2", "Y8": "u1"}
"""librealsense's and the Orbbec SDK's own names for the same layouts."""
IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE_TYPE, COMPRESSED_TYPE)
COMPRESSED_DEPTH_HEADER = 12
"""Bytes of compressedDepth's configuration header before the PNG."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""JPEG start-of-frame markers (those that carry the image size)."""


def encoded_size(data: bytes | memoryview) -> tuple[int, int] | None:
    """(width, height) a PNG (its IHDR) or JPEG (its start of frame) declares, read before decoding; None for
    another format or a header cut short."""
    if data[:8] == PNG_SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack(">II", data[16:24])
        return width, height
    at = 2 if data[:2] == b"\xff\xd8" else len(data)
    while at + 9 <= len(data) and data[at] == 0xFF:
        marker, length = data[at + 1], struct.unpack(">H", data[at + 2:at + 4])[0]
        if marker in JPEG_SOF:
            height, width = struct.unpack(">HH", data[at + 5:at + 9])
            return width, height
        at += 2 + length
    return None


def _checked_size(topic: str, what: str, width: object, height: object) -> None:
    """DamagedMessage when an image of width x height is beyond tofd.drivers.limits' caps."""
    if (problem := image_size_problem(width, height)) is not None:
        raise DamagedMessage(f"{topic}: {what}: {problem}")


def image_plane(msg: Any, encodings: dict[str, str], topic: str) -> np.ndarray:
    """(height, width) array of a sensor_msgs/Image in its own dtype (native byte order), rows of `step` bytes."""
    dtype_code = encodings.get(msg.encoding) or EXTRA_ENCODINGS.get(msg.encoding)
    if dtype_code not in encodings.values():
        raise BagError(f"{topic}: image encoding {msg.encoding!r} is not supported (supported: {', '.join(encodings)})")
    dtype = np.dtype(dtype_code).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    _checked_size(topic, f"a {msg.encoding} image", w, h)
    row_bytes = w * dtype.itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < row_bytes or data.size < h * step:
        raise DamagedMessage(f"{topic}: a {w}x{h} {msg.encoding} image has {data.size} bytes in rows of {step}, "
                             f"expected {h} rows of at least {row_bytes} bytes")
    rows = np.ascontiguousarray(data[:h * step].reshape(h, step)[:, :row_bytes])
    return rows.view(dtype).reshape(h, w).astype(dtype.newbyteorder("="))


def compressed_plane(msg: Any, encodings: dict[str, str], topic: str) -> np.ndarray:
    """(height, width) array of a sensor_msgs/CompressedImage (compressed or compressedDepth): uint8 or uint16
    as stored, float32 metres for a 32FC1 compressedDepth image (NaN where no return)."""
    fmt = str(msg.format)
    encoding, _, method = (part.strip() for part in fmt.partition(";"))
    if encoding not in encodings:
        raise BagError(f"{topic}: compressed image format {fmt!r}: encoding {encoding!r} is not supported "
                       f"(supported: {', '.join(encodings)})")
    data = np.asarray(msg.data, dtype=np.uint8)
    depth = "compresseddepth" in method.lower()
    if depth and "rvl" in method.lower():
        raise BagError(f"{topic}: compressed image format {fmt!r}: RVL compressedDepth is not supported (png is)")
    payload = data[COMPRESSED_DEPTH_HEADER:] if depth else data
    size = encoded_size(np.ascontiguousarray(payload).data)
    if payload.size and size is None:
        raise DamagedMessage(f"{topic}: compressed image format {fmt!r}: {data.size} bytes that are neither a PNG "
                             "nor a JPEG with its size in its header")
    if size is not None:
        _checked_size(topic, f"compressed image format {fmt!r}", *size)
    image = cv2.imdecode(payload, cv2.IMREAD_UNCHANGED) if payload.size else None
    if image is None or image.ndim != 2:
        raise DamagedMessage(f"{topic}: compressed image format {fmt!r}: {data.size} bytes that do not decode to "
                             "a single-channel image")
    if depth and encoding == "32FC1":
        quant_a, quant_b = np.frombuffer(data[4:12].tobytes(), "<f4")
        inverse = image.astype(np.float32)
        with np.errstate(divide="ignore"):
            metres = np.float32(quant_a) / (inverse - np.float32(quant_b))
        metres[image == 0] = np.nan
        return metres.astype(np.float32)
    expected = np.dtype(encodings[encoding]).itemsize
    if image.dtype.itemsize != expected:
        raise BagError(f"{topic}: compressed image format {fmt!r} decodes to {image.dtype}, expected "
                       f"{expected * 8}-bit values")
    return image


def plane(msg: Any, msgtype: str, encodings: dict[str, str], topic: str) -> np.ndarray:
    """The array of an Image or CompressedImage message (by its type)."""
    if msgtype == COMPRESSED_TYPE:
        return compressed_plane(msg, encodings, topic)
    return image_plane(msg, encodings, topic)
