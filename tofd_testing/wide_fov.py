"""Wide-field-of-view scenes for the segmentation tests: a sphere off axis before a wall, seen through a camera's
lens (an Azure Kinect WFOV mode, a RealSense-like 87-degree lens), with the camera's dark pixels outside its lens."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes

WALL_M = 1.6
SPHERE_RADIUS_M = 0.10
OFF_AXIS_DEG = 20.0


def realsense_like_87deg() -> Intrinsics:
    """A 640x480 depth lens of 87 degrees horizontal field of view with Brown-Conrady distortion."""
    fx = 320 / math.tan(math.radians(87 / 2))
    return Intrinsics(640, 480, fx, fx, 319.5, 239.5, distortion_model="plumb_bob",
                      distortion=(0.05, -0.02, 0.001, -0.0005, 0.0))


@dataclass(frozen=True, slots=True)
class WideScene:
    """Radial range (metres, NaN: no return) and amplitude (0 without a return), (H, W) float32; the pixels that
    see the sphere, (H, W) bool; the sphere's centre (3,), camera frame, metres."""

    range_m: np.ndarray
    amplitude: np.ndarray
    sphere: np.ndarray
    centre: np.ndarray


def sphere_before_wall(intrinsics: Intrinsics, distance_m: float, azimuth_deg: float,
                       lens_valid: np.ndarray | None = None, off_axis_deg: float = OFF_AXIS_DEG,
                       radius_m: float = SPHERE_RADIUS_M) -> WideScene:
    """A sphere of radius_m whose centre is distance_m away, off_axis_deg off the optical axis towards
    azimuth_deg (0: +x, 90: +y), before a wall facing the camera at WALL_M (same albedo, Lambertian amplitude);
    pixels outside `lens_valid` have no return, as a wide lens's dark corners."""
    off, az = math.radians(off_axis_deg), math.radians(azimuth_deg)
    centre = distance_m * np.array([math.sin(off) * math.cos(az), math.sin(off) * math.sin(az), math.cos(off)])
    ball = shapes.sphere_at(intrinsics, centre, radius_m)
    wall = shapes.plane(intrinsics, np.array([0.0, 0.0, WALL_M]), np.array([0.0, 0.0, -1.0]))
    scene = ball.over(wall)
    range_m, amplitude = scene.range_m.astype(np.float32), scene.amplitude.astype(np.float32)
    sphere = ball.mask & (ball.range_m <= scene.range_m)
    if lens_valid is not None:
        range_m[~lens_valid], amplitude[~lens_valid], sphere = np.nan, 0.0, sphere & lens_valid
    return WideScene(range_m, amplitude, sphere, centre)
