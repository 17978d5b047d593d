"""Protobuf schemas of a tofd recording: Foxglove's RawImage and CameraCalibration, and tofd.FrameHeader.

tofd.FrameHeader (proto2, built here rather than from a .proto so that no protoc step is needed):

    message FrameHeader {
      optional int64 frame_counter = 1;      // device frame counter
      optional int64 timestamp_us = 2;       // device clock at end of exposure, microseconds
      optional double host_monotonic_s = 3;  // host monotonic clock at receive, seconds
      optional double host_wall_s = 4;       // host wall clock (Unix time) at receive, seconds
      optional Intrinsics intrinsics = 5;    // width, height (pixels), fx, fy, cx, cy (pixels), distortion_model
                                             // (absent: "none"), repeated double distortion (CameraInfo's D)
      optional Device device = 6;            // serial, firmware, backend, model
      optional Registers registers = 7;      // int_time_code, mod_freq_index, acq_mode, data_source,
                                             // amp_threshold; absent: no SR3000 register map (see sensor)
      optional GroundTruth ground_truth = 8; // absent: no ground truth; nose_u, nose_v (pixels), visible,
                                             // nose_xyz_m (camera frame, metres; absent: unknown)
      optional PlaneCodec range = 9;         // how /camera/range's pixels give range_m
      optional PlaneCodec amplitude = 10;    // how /camera/amplitude's pixels give amplitude
      optional Sensor sensor = 11;           // absent: an SR3000 frame (registers) or a file written before it
    }
    message Sensor {  // tofd.drivers.frame.SensorInfo: a non-SR3000 source's signal and settings (registers absent)
      optional double depth_unit_m = 1;     // metres per raw depth value in the source file
      optional string amplitude = 2;        // "amplitude", "ir" or "active_brightness"
      optional int64 invalid_value = 3;     // absent: none
      optional double amplitude_full_scale = 4;  // absent: float amplitude
      optional double unambiguous_range_m = 5;   // absent: unknown
      optional double frame_period_s = 6;        // absent: unknown
      repeated Setting settings = 7;        // the vendor's settings, key -> value, as the file names them
    }
    message Setting { optional string key = 1; optional string value = 2; }
    message PlaneCodec {  // 16UC1 image: value = float32(float64(raw) * scale), raw == invalid -> NaN;
      optional double scale = 1;            // 32FC1 image: the float32 values themselves
      optional uint32 invalid = 2;
    }
"""

from __future__ import annotations

import functools
from typing import Any

from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap_protobuf.schema import build_file_descriptor_set

FieldProto = descriptor_pb2.FieldDescriptorProto
_TYPES = {"int64": FieldProto.TYPE_INT64, "uint32": FieldProto.TYPE_UINT32, "double": FieldProto.TYPE_DOUBLE,
          "string": FieldProto.TYPE_STRING, "bool": FieldProto.TYPE_BOOL}
_MESSAGES: dict[str, list[tuple[str, str]]] = {  # message -> fields (name, type) numbered from 1
    "Intrinsics": [("width", "int64"), ("height", "int64"), ("fx", "double"), ("fy", "double"), ("cx", "double"),
                   ("cy", "double"), ("distortion_model", "string"), ("distortion", "double*")],
    "Device": [("serial", "string"), ("firmware", "string"), ("backend", "string"), ("model", "string")],
    "Registers": [("int_time_code", "int64"), ("mod_freq_index", "int64"), ("acq_mode", "int64"),
                  ("data_source", "int64"), ("amp_threshold", "int64")],
    "Point3": [("x", "double"), ("y", "double"), ("z", "double")],
    "GroundTruth": [("nose_u", "double"), ("nose_v", "double"), ("visible", "bool"), ("nose_xyz_m", "Point3")],
    "PlaneCodec": [("scale", "double"), ("invalid", "uint32")],
    "Setting": [("key", "string"), ("value", "string")],
    "Sensor": [("depth_unit_m", "double"), ("amplitude", "string"), ("invalid_value", "int64"),
               ("amplitude_full_scale", "double"), ("unambiguous_range_m", "double"), ("frame_period_s", "double"),
               ("settings", "Setting*")],
    "FrameHeader": [("frame_counter", "int64"), ("timestamp_us", "int64"), ("host_monotonic_s", "double"),
                    ("host_wall_s", "double"), ("intrinsics", "Intrinsics"), ("device", "Device"),
                    ("registers", "Registers"), ("ground_truth", "GroundTruth"), ("range", "PlaneCodec"),
                    ("amplitude", "PlaneCodec"), ("sensor", "Sensor")],
}
PACKAGE = "tofd"
REPEATED = "*"
"""A field kind ending in REPEATED is a repeated field of that kind."""


def _header_file() -> descriptor_pb2.FileDescriptorProto:
    proto = descriptor_pb2.FileDescriptorProto(name="tofd/FrameHeader.proto", package=PACKAGE, syntax="proto2")
    for name, fields in _MESSAGES.items():
        message = proto.message_type.add(name=name)
        for number, (field, kind) in enumerate(fields, start=1):
            repeated = kind.endswith(REPEATED)
            kind = kind.removesuffix(REPEATED)
            f = message.field.add(name=field, number=number,
                                  label=FieldProto.LABEL_REPEATED if repeated else FieldProto.LABEL_OPTIONAL)
            if kind in _TYPES:
                f.type = _TYPES[kind]
            else:
                f.type, f.type_name = FieldProto.TYPE_MESSAGE, f".{PACKAGE}.{kind}"
    return proto


@functools.cache
def frame_header_class() -> Any:
    """The generated message class of tofd.FrameHeader."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(_header_file())
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{PACKAGE}.FrameHeader"))


@functools.cache
def schema_data(name: str) -> bytes:
    """MCAP schema data (encoding "protobuf": a FileDescriptorSet with dependencies) of the message type `name`."""
    message = {"tofd.FrameHeader": frame_header_class(), "foxglove.RawImage": RawImage,
               "foxglove.CameraCalibration": CameraCalibration}[name]
    return build_file_descriptor_set(message).SerializeToString()


__all__ = ["CameraCalibration", "RawImage", "frame_header_class", "schema_data"]
