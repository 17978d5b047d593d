"""The depth lens of an Azure Kinect / Orbbec Femto from its raw calibration (the calibration.json the device
stores and its recordings attach), per depth mode, as the Azure Kinect SDK computes it.

The raw calibration is for the 1024x1024 sensor, "unitized and 0-cornered" (cx, cy, fx, fy divided by the sensor
size, (0, 0) the corner of the top-left pixel). Each depth mode bins and crops the sensor image; the SDK
(src/transformation/mode_specific_calibration.c) scales by the binned size, subtracts the crop offset and half a
pixel, which gives tofd's convention ((0, 0) the centre of the top-left pixel). The lens is Brown-Conrady with
k1..k6, p1, p2: OpenCV's rational model, i.e. CameraInfo's "rational_polynomial". The SDK also bounds the lens by
a metric radius (undistorted tan of the angle off axis) beyond which no pixel is valid.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from tofd.drivers.intrinsics import Intrinsics

DEPTH_CAMERA_LOCATION = "CALIBRATION_CameraLocationD0"
BROWN_CONRADY = "CALIBRATION_LensDistortionModelBrownConrady"
RAW_SENSOR_SIZE = (1024, 1024)


@dataclass(frozen=True, slots=True)
class DepthModeGeometry:
    """How a depth mode makes its image from the sensor: binned sensor size, crop offset, output size (pixels)."""

    binned: tuple[int, int]
    crop: tuple[int, int]
    output: tuple[int, int]


DEPTH_MODES: dict[str, DepthModeGeometry] = {
    "NFOV_2X2BINNED": DepthModeGeometry((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": DepthModeGeometry((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": DepthModeGeometry((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": DepthModeGeometry((1024, 1024), (0, 0), (1024, 1024)),
    "PASSIVE_IR": DepthModeGeometry((1024, 1024), (0, 0), (1024, 1024)),
}
"""Each K4A_DEPTH_MODE's geometry, as the SDK's transformation_get_mode_specific_depth_camera_calibration has it."""


@dataclass(frozen=True, slots=True)
class DepthLens:
    """A depth mode's intrinsics and the metric radius bounding its lens (tan of the largest angle off axis)."""

    intrinsics: Intrinsics
    metric_radius: float

    def valid_pixels(self) -> np.ndarray:
        """(H, W) bool: the pixels whose ray the SDK accepts (a ray, within the metric radius)."""
        rays = self.intrinsics.unit_rays()
        with np.errstate(invalid="ignore", divide="ignore"):
            tan = np.hypot(rays[..., 0], rays[..., 1]) / rays[..., 2]
        return tan <= self.metric_radius if self.metric_radius > 0 else np.isfinite(tan)


def _depth_camera(calibration: dict) -> dict:
    try:
        cameras = calibration["CalibrationInformation"]["Cameras"]
        return next(c for c in cameras if c.get("Location") == DEPTH_CAMERA_LOCATION)
    except (KeyError, TypeError, AttributeError, StopIteration):
        raise ValueError(f"calibration.json: no CalibrationInformation.Cameras entry with Location "
                         f"{DEPTH_CAMERA_LOCATION!r} (the depth camera)") from None


def depth_lens(calibration_json: bytes | str, depth_mode: str) -> DepthLens:
    """The DepthLens of `depth_mode` (a K4A_DEPTH_MODE tag value) from a raw calibration.json; ValueError names
    the key that is missing or unusable."""
    geometry = DEPTH_MODES.get(depth_mode)
    if geometry is None:
        raise ValueError(f"K4A_DEPTH_MODE {depth_mode!r} has no depth image geometry (known: {', '.join(DEPTH_MODES)})")
    try:
        calibration = json.loads(calibration_json)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise ValueError(f"calibration.json is not JSON (or nested too deeply): {exc}") from None
    camera = _depth_camera(calibration)
    try:
        intrinsics = camera["Intrinsics"]
        model, params = intrinsics["ModelType"], [float(p) for p in intrinsics["ModelParameters"]]
        size = (int(camera["SensorWidth"]), int(camera["SensorHeight"]))
        metric_radius = float(camera["MetricRadius"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"calibration.json: depth camera entry lacks or garbles {exc}") from None
    if model != BROWN_CONRADY:
        raise ValueError(f"calibration.json: depth lens model {model!r} is not supported (tofd reads {BROWN_CONRADY}, "
                         "what retail devices have)")
    if len(params) < 14 or not all(math.isfinite(p) for p in params):
        raise ValueError(f"calibration.json: depth ModelParameters has {len(params)} values, expected 14 finite ones")
    if size != RAW_SENSOR_SIZE:
        raise ValueError(f"calibration.json: depth sensor is {size[0]}x{size[1]}, expected "
                         f"{RAW_SENSOR_SIZE[0]}x{RAW_SENSOR_SIZE[1]}")
    cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, codx, cody, p2, p1 = params[:14]
    if codx != 0 or cody != 0:
        raise ValueError(f"calibration.json: depth lens has a centre of distortion ({codx}, {cody}) off the "
                         "principal point, which Brown-Conrady does not have")
    (bw, bh), (ox, oy), (w, h) = geometry.binned, geometry.crop, geometry.output
    lens = Intrinsics(width=w, height=h, fx=fx * bw, fy=fy * bh, cx=cx * bw - ox - 0.5, cy=cy * bh - oy - 0.5,
                      distortion_model="rational_polynomial", distortion=(k1, k2, p1, p2, k3, k4, k5, k6))
    return DepthLens(lens, metric_radius)
