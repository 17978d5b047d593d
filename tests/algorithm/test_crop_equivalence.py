"""The work done on the foreground's box only gives what the same work on the whole image gives: the segmentation's
mask brought back to every pixel (segmentation.upsampled_box) and the detector's candidate tests on the crop, also
through a distorted lens (the crop's rays are the whole image's)."""

from __future__ import annotations

import numpy as np
import pytest

from tofd.algorithm.detector import border_distance_m, front_gap_m
from tofd.algorithm.detector.candidates import Candidates
from tofd.algorithm.segmentation import bounding_box, upsampled, upsampled_box
from tofd.drivers.intrinsics import Intrinsics


def test_upsampled_box_is_the_box_of_the_upsampled_mask() -> None:
    rng = np.random.default_rng(7)
    for _ in range(500):
        stride = int(rng.integers(1, 5))
        shape = (int(rng.integers(1, 40)), int(rng.integers(1, 40)))
        coarse = np.zeros((-(-shape[0] // stride), -(-shape[1] // stride)), bool)
        for _ in range(int(rng.integers(1, 4))):
            coarse[rng.integers(0, coarse.shape[0]), rng.integers(0, coarse.shape[1])] = True
        full = upsampled(coarse, shape, stride)
        box, near = upsampled_box(coarse, shape, stride)
        assert box == bounding_box(full), (shape, stride)
        np.testing.assert_array_equal(near, full[box])


def sphere_range(intrinsics: Intrinsics, centre: tuple[float, float, float], radius: float) -> np.ndarray:
    """(H, W) float32 radial range to a sphere along each pixel's ray (NaN where the ray misses it)."""
    rays, c = intrinsics.unit_rays(), np.asarray(centre)
    along = rays @ c
    disc = along**2 - (c @ c - radius**2)
    with np.errstate(invalid="ignore"):
        return np.where(disc > 0, along - np.sqrt(disc), np.nan).astype(np.float32)


@pytest.mark.parametrize("intrinsics", [
    Intrinsics(),
    Intrinsics(176, 144, 200.0, 200.0, 80.0, 75.0, "plumb_bob", (-0.6, 0.3, 0.002, -0.001, 0.0)),
    Intrinsics(640, 576, 504.0, 504.0, 319.5, 287.5, "rational_polynomial",
               (0.5, -0.1, 0.0, 0.0, 0.0, 0.8, -0.05, 0.0)),
], ids=["sr3000", "distorted", "k4a-like-distorted"])
def test_candidates_on_the_crop_equal_the_tests_on_the_whole_image(intrinsics: Intrinsics) -> None:
    range_m = sphere_range(intrinsics, (0.09, -0.07, 0.5), 0.08)  # off the axis, where the lens bends the rays
    rng = np.random.default_rng(3)
    range_m += rng.normal(0.0, 0.001, range_m.shape).astype(np.float32)  # the front test sees noise
    foreground = np.isfinite(range_m)
    assert 0.05 < foreground.mean() < 0.5
    direction = np.array([0.05, -0.03, 1.0]) / np.linalg.norm([0.05, -0.03, 1.0])
    candidates = Candidates(border_margin_m=0.006, front_depth_m=0.001, median_px=5)
    whole = foreground & candidates.keep(border_distance_m(foreground, range_m, intrinsics),
                                         front_gap_m(foreground, range_m, intrinsics, direction, median_px=5))
    got = candidates.mask(foreground, range_m, intrinsics, direction)
    if intrinsics.width == 176:  # stride 1: the crop's front test samples as the whole image's does
        np.testing.assert_array_equal(got, whole)
    assert got.any() and np.all(got <= foreground)
    border = border_distance_m(foreground, range_m, intrinsics) >= candidates.border_margin_m
    np.testing.assert_array_equal(got & ~border, np.zeros_like(got))  # the border test as on the whole image
    rows, cols = candidates.pixels(foreground, range_m, intrinsics, direction)
    np.testing.assert_array_equal(np.flatnonzero(got), rows * intrinsics.width + cols)
