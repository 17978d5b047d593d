"""Sub-pixel nose tip: the front-most point of the surface near the accepted pixel, fitted locally in 3-D.

The detector's best pixel is where the features look most like a nose tip, which at close range lies a few
pixels beside the tip itself. The tip is the point of the nose surface nearest the camera along the face's
viewing direction. That direction is the normal of a plane fitted to the face around the nose: the surface points
RING_M from the pixel's point laterally and at most RING_DEPTH_M behind it (cheeks, upper lip, brow), which turn
with the head where the segmentation's face front (its few centimetres nearest the camera) does not follow a yaw.
Then the foreground points within `radius_m` (laterally, in the face frame) of the current estimate are fitted by
least squares with a quadric depth h(x, y) = a + b x + c y + d x^2 + e x y + f y^2, its minimum (a cap facing the
camera: positive-definite Hessian) is the new estimate, and the window is re-centred on it for `iterations` rounds;
a minimum farther than MAX_STEP_RADII radii from the window's centre is approached by a step of that length instead
(a window that straddles the side of the nose extrapolates past the tip). Points more than OUTLIER_SIGMAS robust
standard deviations off the first fit (flying pixels) are dropped before the second. The tip is never moved farther
than `radius_m` x MAX_SHIFT_RADII from the accepted pixel's point; a window that cannot be fitted keeps the last
estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.segmentation import coarse_stride, rotation_to_z
from tofd.drivers.intrinsics import Intrinsics

MIN_POINTS = 8  # fewer foreground points in the window than this: no fit (6 coefficients)
OUTLIER_SIGMAS = 3.0  # residuals beyond this many robust sigmas (1.4826 x MAD) are dropped before refitting
MAX_STEP_RADII = 0.5  # one round moves the window at most this many radii (toward the fitted minimum)
MAX_SHIFT_RADII = 1.0  # the tip stays within this many radii of the accepted pixel's point (a minimum found
# farther off is an extrapolation along a flat ridge, not the tip)
RING_M = (0.03, 0.065)  # metres: inner and outer lateral radius of the ring the face plane is fitted to
RING_DEPTH_M = 0.08  # metres: ring points at most this far behind the pixel's point (not the wall behind the head)
MIN_RING_POINTS = 20  # fewer: keep the segmentation's direction


@dataclass(frozen=True, slots=True)
class Tip:
    """The refined tip: camera-frame point (metres) and its sub-pixel image position (u, v)."""

    xyz_m: tuple[float, float, float]
    px: tuple[float, float]
    fitted: bool  # False: the window could not be fitted and the tip is the accepted pixel's point


def _fit_minimum(x: np.ndarray, y: np.ndarray, h: np.ndarray, max_step: float = np.inf
                 ) -> tuple[np.ndarray, float, np.ndarray] | None:
    """Least-squares quadric h(x, y); (its minimum (2,), or the point max_step toward it if that is farther; h there;
    residuals) or None if it has no minimum."""
    design = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)
    coef, *_ = np.linalg.lstsq(design, h, rcond=None)
    _, b, c, d, e, f = coef
    hessian = np.array([[2 * d, e], [e, 2 * f]])
    if not (hessian[0, 0] > 0 and np.linalg.det(hessian) > 0):
        return None
    at = np.linalg.solve(hessian, -np.array([b, c]))
    at *= min(1.0, max_step / max(float(np.hypot(*at)), 1e-300))
    value = float(coef @ np.array([1.0, at[0], at[1], at[0] ** 2, at[0] * at[1], at[1] ** 2]))
    return at, value, h - design @ coef


def _window(range_m: np.ndarray, intrinsics: Intrinsics, pixel: tuple[int, int], half: int
            ) -> tuple[tuple[slice, slice], np.ndarray]:
    """A (2 half + 1)^2 window about pixel (u, v), every coarse_stride-th pixel through the pixel itself: its
    (rows, cols) slices and the (K, 3) float64 points of its valid pixels, metres."""
    u0, v0 = pixel
    h, w = range_m.shape
    s = coarse_stride(intrinsics)
    rows = slice(v0 - min(half, v0) // s * s, min(v0 + half + 1, h), s)
    cols = slice(u0 - min(half, u0) // s * s, min(u0 + half + 1, w), s)
    window = range_m[rows, cols]
    valid = np.isfinite(window) & (window > 0)
    return (rows, cols), intrinsics.unit_rays()[rows, cols][valid] * window[valid][:, None].astype(np.float64)


def face_rotation(range_m: np.ndarray, intrinsics: Intrinsics, pixel: tuple[int, int], rotation: np.ndarray
                  ) -> np.ndarray:
    """(3, 3) camera -> face frame whose row 2 is the normal of the plane fitted to the ring about `pixel` (module
    docstring); `rotation` (the segmentation's) selects the ring and is returned when it is too sparse."""
    u0, v0 = pixel
    start = intrinsics.unit_rays()[v0, u0] * float(range_m[v0, u0])
    half = int(np.ceil(RING_M[1] * max(intrinsics.fx, intrinsics.fy) / max(start[2], 1e-3)))
    _, points = _window(range_m, intrinsics, pixel, half)
    local = (points - start) @ rotation.T
    lateral = np.hypot(local[:, 0], local[:, 1])
    ring = points[(lateral >= RING_M[0]) & (lateral <= RING_M[1]) & (local[:, 2] <= RING_DEPTH_M)
                  & (local[:, 2] >= -RING_M[0])]
    if len(ring) < MIN_RING_POINTS:
        return rotation
    normal = np.linalg.svd(ring - ring.mean(axis=0), full_matrices=False)[2][2]
    return rotation_to_z(normal * (np.sign(normal[2]) or 1.0))


def refine_tip(range_m: np.ndarray, foreground: np.ndarray, intrinsics: Intrinsics, pixel: tuple[int, int],
               rotation: np.ndarray, radius_m: float, iterations: int = 3, max_step_radii: float = MAX_STEP_RADII
               ) -> Tip:
    """The tip near `pixel` (u, v) of a frame (module docstring).

    range_m: (H, W) radial range, metres; foreground: (H, W) bool, the pixels the surface is fitted to;
    rotation: (3, 3) camera -> face frame, row 2 the face's viewing direction (segmentation.Foreground.rotation),
    refined about the pixel by face_rotation. max_step_radii: one round's longest step, radii (MAX_STEP_RADII).
    Only windows about the pixel are read (the ring's, and 2 radii for the fit), every stride-th pixel of them
    on cameras of finer pixels than the reference (segmentation.coarse_stride): a fit needs the surface's shape, not
    every sample.
    """
    u0, v0 = pixel
    start = intrinsics.unit_rays()[v0, u0] * float(range_m[v0, u0])
    best = start
    fitted = False
    rotation = face_rotation(range_m, intrinsics, pixel, rotation)
    half = int(np.ceil(radius_m * (1 + MAX_SHIFT_RADII) * max(intrinsics.fx, intrinsics.fy) / max(start[2], 1e-3)))
    box, _ = _window(range_m, intrinsics, pixel, half)
    win = foreground[box] & np.isfinite(range_m[box])
    points = intrinsics.unit_rays()[box][win] * range_m[box][win][:, None].astype(np.float64)
    local = points @ rotation.T  # face frame: x, y lateral, z depth along the viewing direction
    centre = rotation @ start
    step = radius_m * max_step_radii
    for _ in range(max(iterations, 0)):
        near = np.hypot(local[:, 0] - centre[0], local[:, 1] - centre[1]) <= radius_m
        if np.count_nonzero(near) < MIN_POINTS:
            break
        x, y, z = local[near, 0] - centre[0], local[near, 1] - centre[1], local[near, 2]
        fit = _fit_minimum(x, y, z, step)
        if fit is not None:
            keep = np.abs(fit[2]) <= OUTLIER_SIGMAS * 1.4826 * np.median(np.abs(fit[2])) + 1e-9
            if np.count_nonzero(keep) >= MIN_POINTS and not keep.all():
                fit = _fit_minimum(x[keep], y[keep], z[keep], step)
        if fit is None:
            break
        at, depth, _ = fit
        moved = np.array([centre[0] + at[0], centre[1] + at[1], depth])
        shift = moved[:2] - (rotation @ start)[:2]
        limit = radius_m * MAX_SHIFT_RADII
        if np.hypot(*shift) > limit:  # a minimum beyond the limit is not the tip: keep the last estimate
            break
        centre, fitted = moved, True
        best = rotation.T @ centre
    u, v = intrinsics.project(best)
    return Tip((float(best[0]), float(best[1]), float(best[2])), (float(u), float(v)), fitted)
