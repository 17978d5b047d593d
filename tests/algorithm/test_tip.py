"""The sub-pixel nose tip (tofd.algorithm.detector.tip) on analytic surfaces: a sphere's apex along the viewing
direction, from an accepted pixel a few pixels off it."""

import numpy as np
import pytest

from tofd.algorithm.detector.tip import refine_tip
from tofd.algorithm.segmentation import rotation_to_z
from tofd.drivers.intrinsics import Intrinsics


def sphere_range(intrinsics: Intrinsics, centre: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) radial range to the near side of a sphere (NaN where the ray misses it)."""
    rays = intrinsics.unit_rays()
    b = rays @ centre
    disc = b**2 - centre @ centre + radius**2
    with np.errstate(invalid="ignore"):
        return np.where(disc > 0, b - np.sqrt(disc), np.nan)


@pytest.mark.parametrize("intrinsics", [Intrinsics(), Intrinsics(640, 576, 504.0, 504.0, 319.5, 287.5)])
@pytest.mark.parametrize("tilt_deg", [0.0, 20.0])
def test_tip_is_the_apex_along_the_viewing_direction(intrinsics, tilt_deg):
    centre, radius = np.array([0.01, -0.02, 0.45]), 0.02
    direction = np.array([np.sin(np.radians(tilt_deg)), 0.0, np.cos(np.radians(tilt_deg))])
    apex = centre - radius * direction
    range_m = sphere_range(intrinsics, centre, radius)
    u, v = intrinsics.project(apex)
    start = (int(round(u)) + 3, int(round(v)) - 2)  # the box's best pixel, beside the tip
    tip = refine_tip(range_m, np.isfinite(range_m), intrinsics, start, rotation_to_z(direction), 0.012)
    assert tip.fitted
    assert np.linalg.norm(np.asarray(tip.xyz_m) - apex) < 2e-4
    assert np.hypot(tip.px[0] - u, tip.px[1] - v) < 0.2
    assert np.allclose(intrinsics.project(np.asarray(tip.xyz_m)), tip.px)


def test_noisy_tip_is_closer_than_the_pixel():
    intrinsics = Intrinsics()
    centre, radius = np.array([0.0, 0.0, 0.35]), 0.02
    apex = centre - radius * np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(3)
    range_m = sphere_range(intrinsics, centre, radius) + rng.normal(0, 0.002, intrinsics.shape)
    u, v = intrinsics.project(apex)
    start = (int(round(u)) + 4, int(round(v)))
    tip = refine_tip(range_m, np.isfinite(range_m), intrinsics, start, np.eye(3), 0.016)
    assert np.hypot(tip.px[0] - u, tip.px[1] - v) < 1.5
    assert np.linalg.norm(np.asarray(tip.xyz_m) - apex) < 0.003


def test_a_window_without_a_cap_keeps_the_pixel():
    intrinsics = Intrinsics()
    range_m = np.full(intrinsics.shape, 0.5)  # a sphere about the camera: no apex along z within the window
    tip = refine_tip(range_m, np.ones(intrinsics.shape, bool), intrinsics, (40, 50), np.eye(3), 0.01)
    point = intrinsics.unit_rays()[50, 40] * 0.5
    assert not tip.fitted
    assert np.allclose(tip.xyz_m, point) and tip.px == pytest.approx((40, 50))


@pytest.mark.parametrize("offset_m", [0.008, 0.012, 0.014])
def test_a_pixel_on_the_side_of_the_nose_reaches_the_tip(offset_m):
    """A 2 cm hemisphere on a plane (a nose on a face) seen by a 640x576 camera, the accepted pixel beside the apex:
    the first window straddles the nose's side and its quadric's minimum lies far past the apex; the tip steps
    toward it and re-fits rather than stopping at the pixel."""
    intrinsics = Intrinsics(640, 576, 504.0, 504.0, 319.5, 287.5)
    centre, radius = np.array([0.0, 0.0, 0.62]), 0.02
    nose = sphere_range(intrinsics, centre, radius)
    face = centre[2] / intrinsics.unit_rays()[..., 2]
    range_m = np.fmin(nose, face)
    apex = centre - np.array([0.0, 0.0, radius])
    u, v = intrinsics.project(apex + np.array([offset_m, 0.0, 0.0]))
    tip = refine_tip(range_m, np.isfinite(range_m), intrinsics, (int(round(u)), int(round(v))),
                     rotation_to_z(np.array([0.0, 0.0, 1.0])), 0.016)
    assert tip.fitted
    assert np.linalg.norm(np.asarray(tip.xyz_m) - apex) < 1e-3
