"""The topics tofd publishes to Foxglove, their schemas, and the frames they are in (one owner of the names).

Frames: CAMERA_FRAME is the camera's optical frame (x right, y down, z forward, metres; the frame_id of tofd's
recordings); WORLD_FRAME is fixed, x forward, y left, z up (ROS REP 103), with the camera at its origin.
"""

from __future__ import annotations

from tofd.algorithm.names import VIEWED_MAPS

CAMERA_FRAME = "camera"
WORLD_FRAME = "world"

RANGE = "/camera/range"  # foxglove.RawImage 32FC1: radial range along each pixel's ray, metres (NaN: invalid)
AMPLITUDE = "/camera/amplitude"  # foxglove.RawImage 16UC1: amplitude, sensor units
MASK = "/camera/mask"  # foxglove.RawImage mono8: 255 foreground, 0 background
CALIBRATION = "/camera/calibration"  # foxglove.CameraCalibration: the intrinsics (K, P; ROS pixel convention)
NOSE = "/camera/nose"  # foxglove.ImageAnnotations: the detected nose tip (none: no annotation)
NOSE_TRACK = "/camera/nose_track"  # foxglove.ImageAnnotations: the confirmed nose track's box and confidence
FOREGROUND = "/foreground"  # foxglove.PointCloud: foreground points (x, y, z metres, NFFT eps0) in CAMERA_FRAME
TRANSFORM = "/tf"  # foxglove.FrameTransform: WORLD_FRAME -> CAMERA_FRAME
FEATURES = {name: "/features/" + name.removeprefix("range_").replace("_", "/") for name in VIEWED_MAPS}
"""Feature map name -> topic (range_fft_eps0 -> /features/fft/eps0): foxglove.RawImage 32FC1, 0 outside the
foreground."""

SCHEMAS = {RANGE: "foxglove.RawImage", AMPLITUDE: "foxglove.RawImage", MASK: "foxglove.RawImage",
           CALIBRATION: "foxglove.CameraCalibration", NOSE: "foxglove.ImageAnnotations",
           NOSE_TRACK: "foxglove.ImageAnnotations", FOREGROUND: "foxglove.PointCloud",
           TRANSFORM: "foxglove.FrameTransform", **dict.fromkeys(FEATURES.values(), "foxglove.RawImage")}
"""Every topic and the schema of its messages (protobuf encoded)."""

OPTICAL_IN_WORLD = (-0.5, 0.5, -0.5, 0.5)
"""Quaternion (x, y, z, w) of CAMERA_FRAME's axes in WORLD_FRAME: z forward -> x, x right -> -y, y down -> -z."""
