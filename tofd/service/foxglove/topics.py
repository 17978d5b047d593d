"""The topics tofd publishes to Foxglove, their schemas, and the frames they are in (one owner of the names).

Frames: CAMERA_FRAME is the camera's optical frame (x right, y down, z forward, metres; the frame_id of tofd's
recordings); WORLD_FRAME is fixed, x forward, y left, z up (ROS REP 103), with the camera at its origin.
"""

from __future__ import annotations

from tofd.algorithm.names import VIEWED_MAPS

CAMERA_FRAME = "camera"
WORLD_FRAME = "world"

RANGE = "/camera/range"
"""The range image, chosen at the first frame (its channel's metadata, range_metadata, says which):
foxglove.CompressedImage, a 16-bit PNG of the source's own integers where they are exact (z-depth in millimetres
of a millimetre camera; the SR3000's radial range codes), 0 where invalid; else foxglove.RawImage 32FC1: radial
range along each pixel's ray, metres (NaN: invalid)."""
AMPLITUDE = "/camera/amplitude"  # foxglove.CompressedImage, 8-bit JPEG: amplitude for viewing (AMPLITUDE_SCALE)
TIMESTAMP_SCHEMA = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
"""The JSON topics' timestamp: seconds and nanoseconds of the host's wall clock, as the protobuf topics'."""
AMPLITUDE_SCALE = "/camera/amplitude_scale"
"""JSON (AMPLITUDE_SCALE_SCHEMA): the amplitude image's scale, sensor units per 8-bit level, with its timestamp."""
AMPLITUDE_SCALE_SCHEMA = {
    "type": "object", "title": "tofd.AmplitudeScale",
    "properties": {"timestamp": TIMESTAMP_SCHEMA,
                   "units_per_level": {"type": "number"}}}
MASK = "/camera/mask"  # foxglove.CompressedImage, 1-bit PNG: white foreground, black background
CALIBRATION = "/camera/calibration"  # foxglove.CameraCalibration: the intrinsics (K, P; ROS pixel convention)
NOSE = "/camera/nose"  # foxglove.ImageAnnotations: the detected nose tip (none: no annotation)
NOSE_TRACK = "/camera/nose_track"  # foxglove.ImageAnnotations: the confirmed nose track's box and confidence
FOREGROUND = "/foreground"  # foxglove.PointCloud: foreground points (x, y, z metres, NFFT eps0) in CAMERA_FRAME
TRANSFORM = "/tf"  # foxglove.FrameTransform: WORLD_FRAME -> CAMERA_FRAME
FEATURES = {name: "/features/" + name.removeprefix("range_").replace("_", "/") for name in VIEWED_MAPS}
"""Feature map name -> topic (range_fft_eps0 -> /features/fft/eps0): foxglove.CompressedImage, an 8-bit PNG of
the foreground's bounding box only (FEATURE_BOX says where it lies and what its levels are), 0 outside the
foreground, 255 the map's largest value in the frame."""
FEATURE_BOX = "/features/box"
"""JSON (FEATURE_BOX_SCHEMA), per frame: the feature maps' crop in the image (x, y: its top-left pixel; width,
height) and per map topic its value at level 255 (a level's value is level / 255 of it)."""
FEATURE_BOX_SCHEMA = {
    "type": "object", "title": "tofd.FeatureBox",
    "properties": {"timestamp": TIMESTAMP_SCHEMA,
                   "x": {"type": "integer"}, "y": {"type": "integer"},
                   "width": {"type": "integer"}, "height": {"type": "integer"},
                   "top": {"type": "object", "additionalProperties": {"type": "number"}}}}
FEATURE_METADATA = {"crop": f"the foreground's bounding box; its place and levels: {FEATURE_BOX}"}

SCHEMAS = {RANGE: "foxglove.CompressedImage | foxglove.RawImage", AMPLITUDE: "foxglove.CompressedImage",
           AMPLITUDE_SCALE: "tofd.AmplitudeScale", FEATURE_BOX: "tofd.FeatureBox",
           MASK: "foxglove.CompressedImage", CALIBRATION: "foxglove.CameraCalibration",
           NOSE: "foxglove.ImageAnnotations", NOSE_TRACK: "foxglove.ImageAnnotations",
           FOREGROUND: "foxglove.PointCloud", TRANSFORM: "foxglove.FrameTransform",
           **dict.fromkeys(FEATURES.values(), "foxglove.CompressedImage")}
"""Every topic and the schema of its messages (protobuf encoded, JSON_TOPICS JSON; RANGE: one of two, per source)."""
JSON_TOPICS = (AMPLITUDE_SCALE, FEATURE_BOX)


def range_metadata(depth: str, unit_m: float) -> dict[str, str]:
    """The RANGE channel's metadata: "depth" ("z" along the optical axis or "radial" along each pixel's ray) and
    "unit_m" (metres per stored step; 1 for float metres)."""
    return {"depth": depth, "unit_m": repr(unit_m)}

OPTICAL_IN_WORLD = (-0.5, 0.5, -0.5, 0.5)
"""Quaternion (x, y, z, w) of CAMERA_FRAME's axes in WORLD_FRAME: z forward -> x, x right -> -y, y down -> -z."""
