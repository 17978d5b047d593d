"""Image geometry shared by the viewers (Rerun, Foxglove): the pixel-centre convention and the track's box.

tofd (Intrinsics, detections, results) puts (0, 0) at the CENTRE of the top-left pixel, as ROS CameraInfo and
OpenCV do; Rerun (Pinhole principal point, 2-D points and boxes) and Foxglove's ImageAnnotations put it at the
top-left pixel's CORNER. A pixel coordinate goes to a viewer plus CENTRE_TO_CORNER_PX; calibrations in ROS's
convention (foxglove.CameraCalibration K, P) keep tofd's.
"""

from __future__ import annotations

import numpy as np

from tofd.algorithm.segmentation import foreground_box
from tofd.algorithm.tracking import TrackState
from tofd.drivers.intrinsics import Intrinsics
from tofd.service.pipeline.results import track_px

CENTRE_TO_CORNER_PX = 0.5
"""Pixels added to a tofd pixel coordinate (u or v) for a viewer whose origin is the top-left pixel's corner."""


def corner_origin(uv: np.ndarray | tuple[float, float]) -> np.ndarray:
    """(..., 2) float64 pixel coordinates (u, v) with the origin at the top-left pixel's corner, from tofd's
    (origin at that pixel's centre)."""
    return np.asarray(uv, dtype=np.float64) + CENTRE_TO_CORNER_PX


TRACK_BOX_M = 0.03
"""Metres: side of the box drawn about the nose track in the image, at the track's depth (a nose's size)."""


def track_box_px(track: TrackState | None, intrinsics: Intrinsics) -> tuple[tuple[float, float], float] | None:
    """The confirmed track's box in a viewer's pixels: its centre (u, v) with the origin at the top-left pixel's
    corner, and its half side in pixels; None while no track is reported."""
    px = track_px(track, intrinsics)
    if px is None or track is None or track.nose_xyz_m is None:
        return None
    half = TRACK_BOX_M / 2 * intrinsics.fx / track.nose_xyz_m[2]
    return (px[0] + CENTRE_TO_CORNER_PX, px[1] + CENTRE_TO_CORNER_PX), half


def shown_box(box: tuple[slice, slice]) -> tuple[slice, slice]:
    """The (rows, cols) a view crops the mask and the feature maps to: the foreground's box (FrameResult.box), or the
    top-left pixel when the foreground is empty (a viewer's image has at least one pixel)."""
    rows, cols = box
    return box if rows.stop > rows.start and cols.stop > cols.start else (slice(0, 1), slice(0, 1))


CLOUD_POINTS = 6000
"""Most foreground points a viewer's 3-D view gets per frame (a density it draws at the camera's rate)."""


def cloud_pixels(mask: np.ndarray, most: int = CLOUD_POINTS, box: tuple[slice, slice] | None = None) -> np.ndarray:
    """Flat indices (row * W + column) of cloud_grid's pixels."""
    rows, cols = cloud_grid(mask, most, box)
    return rows * mask.shape[1] + cols


def cloud_grid(mask: np.ndarray, most: int = CLOUD_POINTS, box: tuple[slice, slice] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the (H, W) mask's pixels on the grid of every k-th row and column (k >= 1 the least that
    keeps at most `most` of them), in row-major order: every pixel while the foreground is small, else an even
    subsample of it. `box`: the mask's segmentation.foreground_box, if known (only it is searched)."""
    rows, cols = foreground_box(mask) if box is None else box
    step = 1
    while True:
        first_row, first_col = -(-rows.start // step) * step, -(-cols.start // step) * step  # on the grid
        on_grid = mask[first_row:rows.stop:step, first_col:cols.stop:step]
        if np.count_nonzero(on_grid) <= most:
            break
        step += 1
    at_row, at_col = np.nonzero(on_grid)
    return at_row * step + first_row, at_col * step + first_col
