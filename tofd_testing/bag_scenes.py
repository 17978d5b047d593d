"""A known scene rendered through a real lens model, for the vendor-recording tests: a sphere in the distorted
corner of the image in front of a tilted plane. Rays come from OpenCV's undistortPoints (cv2.fisheye for
equidistant), independent of tofd's own lens code; the images are what a camera would deliver: z-depth in
its units (0 = no return) and an infrared image falling off as cos / r^2."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from tofd.drivers.intrinsics import Intrinsics


@dataclass(frozen=True)
class Scene:
    centre: tuple[float, float, float] = (0.26, 0.2, 0.55)  # metres, camera frame; towards the lower right corner
    radius: float = 0.1
    plane_normal: tuple[float, float, float] = (0.25, -0.1, -1.0)  # a wall 1.6 m away, tilted
    plane_offset: float = -1.6  # n . p = offset (n unnormalised)


RS_LIKE = Intrinsics(256, 192, 200.0, 201.0, 129.3, 94.6, "plumb_bob", (-0.25, 0.09, 0.0012, -0.0009, -0.012))
"""A RealSense-like camera: librealsense's Brown-Conrady lens (ROS plumb_bob), wide-angle barrel distortion."""
RS_SCENE = Scene(centre=(0.22, 0.16, 0.55))
"""The sphere of RS_LIKE's scene, inside its narrower view."""
K4A_LIKE = Intrinsics(320, 288, 262.6, 264.7, 156.3, 140.4, "rational_polynomial",
                      (0.548, -0.021, 2.06e-5, -7.2e-5, -0.00265, 0.8897, 0.0861, -0.0139))
"""An Azure Kinect depth camera in NFOV 2x2 binned: a real device's Brown-Conrady k1-k6 (ROS rational_polynomial)."""
FISHEYE_LIKE = Intrinsics(224, 172, 150.0, 150.0, 111.0, 86.5, "equidistant", (0.05, -0.01, 0.002, -0.0005))


@functools.lru_cache(maxsize=4)
def opencv_rays(intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) rays (x, y, 1) of every pixel, undistorted by OpenCV (made once per lens: read only)."""
    i = intrinsics
    u, v = np.meshgrid(np.arange(i.width, dtype=np.float64), np.arange(i.height, dtype=np.float64))
    pixels = np.stack([u, v], -1).reshape(-1, 1, 2)
    k = np.array([[i.fx, 0, i.cx], [0, i.fy, i.cy], [0, 0, 1]])
    d = np.array(i.distortion, np.float64)
    if i.distortion_model == "equidistant":
        xy = cv2.fisheye.undistortPoints(pixels, k, d)
    else:
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        xy = cv2.undistortPoints(pixels, k, d, R=np.eye(3), P=np.eye(3), criteria=criteria)
    xy = xy.reshape(i.height, i.width, 2)
    return np.concatenate([xy, np.ones((i.height, i.width, 1))], -1)


def render(intrinsics: Intrinsics, scene: Scene = Scene()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(z-depth in metres, NaN = no hit; infrared in [0, 1]; bool mask of the sphere) of the scene."""
    rays = opencv_rays(intrinsics)
    c = np.asarray(scene.centre)
    a = np.einsum("hwk,hwk->hw", rays, rays)
    b = -2 * rays @ c
    disc = b * b - 4 * a * (c @ c - scene.radius ** 2)
    with np.errstate(invalid="ignore"):
        t_sphere = (-b - np.sqrt(disc)) / (2 * a)
    on_sphere = disc > 0
    n = np.asarray(scene.plane_normal, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane = scene.plane_offset / (rays @ n)
    t = np.where(on_sphere, t_sphere, np.where(t_plane > 0, t_plane, np.nan))
    points = rays * t[..., None]
    normals = np.where(on_sphere[..., None], (points - c) / scene.radius, n / np.linalg.norm(n))
    distance = np.linalg.norm(points, axis=-1)
    cosine = np.abs(np.einsum("hwk,hwk->hw", normals, points)) / distance
    infrared = np.clip(0.05 * cosine / distance ** 2, 0, 1)
    return t.astype(np.float64), np.nan_to_num(infrared), on_sphere


def sphere_errors(points: np.ndarray, scene: Scene = Scene()) -> np.ndarray:
    """Distance of each (N, 3) point from the sphere's surface, metres."""
    return np.abs(np.linalg.norm(points - np.asarray(scene.centre), axis=-1) - scene.radius)


def depth_units(z_m: np.ndarray, metres_per_unit: float) -> np.ndarray:
    """uint16 depth in units, 0 where there is no return."""
    raw = np.rint(np.nan_to_num(z_m, nan=0.0) / metres_per_unit)
    return np.clip(raw, 0, 65535).astype(np.uint16)
