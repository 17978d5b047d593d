"""Which foreground pixels may be the nose tip at all, before the box is consulted.

Border test: pixels nearer than `border_margin_m` to the mask border are never candidates, because the filters'
response within about one filter width of the border is the clamped background's. Front test: the tip is the
front-most point of its surroundings, so a pixel more than `front_depth_m` behind the front-most foreground
pixel within FRONT_RADIUS_M (depth along the face's viewing direction) is never a candidate. The allowance
scales with the expected noise at the pixel: front_depth_m + front_noise_factor * sigma, sigma the local range
noise estimated from the frame itself (depth_noise_m), because range noise grows with distance and falls with
amplitude and a fixed allowance rejects the true tip wherever the noise is larger than on the training data.

The tests run on the foreground's bounding box (plus CROP_MARGIN_PX, aligned to CROP_ALIGN_PX), with the whole
image's rays cut to it: at modern resolutions the face covers a fraction of the frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tofd.algorithm.params import DetectorConfig, SegmentationConfig
from tofd.algorithm.segmentation import bounding_box, coarse_stride, filtered, upsampled
from tofd.drivers.intrinsics import Intrinsics


def border_distance_m(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics, *,
                      rays: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 distance in metres from each mask pixel to the mask border or image edge (0 off the mask).

    Pixels: Euclidean distance to the nearest non-mask pixel (outside the image counts as non-mask) minus half a
    pixel; metres: times the pixel's depth (range * z of its unit ray) / fx.
    rays: (H, W, 3) unit rays of these pixels (default: intrinsics.unit_rays(); a crop passes the whole image's
    cut to it, as `Candidates` does).
    """
    rays = intrinsics.unit_rays() if rays is None else rays
    padded = np.pad(np.asarray(mask, dtype=np.uint8), 1)
    px = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    with np.errstate(invalid="ignore"):
        metres = np.maximum(px - 0.5, 0) * (np.asarray(range_m) * rays[..., 2]) / intrinsics.fx
    return np.where(mask, np.nan_to_num(metres, nan=0.0), 0.0).astype(np.float32)


FRONT_RADIUS_M = 0.012  # the front test's neighbourhood: about the nose tip's own radius of curvature


def front_gap_m(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics, direction: np.ndarray | None = None,
                radius_m: float = FRONT_RADIUS_M, median_px: int = 5, *, rays: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 metres each mask pixel lies behind the front-most mask pixel within radius_m (0 off the mask).

    Depth along `direction` (unit, camera frame; default the camera's z axis), median-filtered over median_px
    pixels (the segmentation's filter: a minimum of unfiltered noisy depths lies in front of the surface);
    the disc's radius in pixels is radius_m at the mask's median depth. On a camera of finer pixels the test runs
    on every coarse_stride-th pixel and each pixel takes the gap of the sample nearest it, so that the median and
    the minimum see the surface (and the noise) as on the reference camera.
    rays: (H, W, 3) unit rays of these pixels (default: intrinsics.unit_rays(); a crop passes the whole image's
    cut to it, as `Candidates` does).
    """
    depth, valid = _face_depth(mask, range_m, intrinsics.unit_rays() if rays is None else rays, direction)
    if not valid.any():
        return np.zeros(valid.shape, np.float32)
    median_m = float(np.median(depth[valid]))
    stride = coarse_stride(intrinsics)
    r_px = max(1, round(min(radius_m * intrinsics.fx / stride / median_m if median_m > 0 else np.inf,
                            max(valid.shape))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r_px + 1, 2 * r_px + 1))
    if stride == 1:
        smooth = filtered(depth, valid, median_px)
        gap = smooth - cv2.erode(smooth, disc)
    else:
        sampled = filtered(depth[::stride, ::stride], valid[::stride, ::stride], median_px)
        gap = upsampled(sampled - cv2.erode(sampled, disc), valid.shape, stride)
    return np.where(valid, gap, 0.0).astype(np.float32)


def _face_depth(mask: np.ndarray, range_m: np.ndarray, rays: np.ndarray, direction: np.ndarray | None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Depth along direction (H, W) and the valid mask pixels."""
    with np.errstate(invalid="ignore"):
        depth = np.asarray(range_m) * (rays[..., 2] if direction is None else rays @ direction)
    return depth, np.asarray(mask, dtype=bool) & np.isfinite(depth)


NOISE_WINDOW_PX = 7  # window of the local noise estimate, pixels


def depth_noise_m(mask: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics, direction: np.ndarray | None = None,
                  median_px: int = 5, *, rays: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 local range noise standard deviation in metres (0 off the mask), estimated from the frame.

    sigma = sqrt(pi / 2) * mean |depth - median_px median of depth| over the mask pixels of a NOISE_WINDOW_PX
    window (the mean absolute deviation of Gaussian noise is sigma sqrt(2 / pi)); the face's own curvature within
    the median window adds well under a millimetre.
    rays: (H, W, 3) unit rays of these pixels (default: intrinsics.unit_rays(); a crop passes the whole image's
    cut to it, as `Candidates` does).
    """
    depth, valid = _face_depth(mask, range_m, intrinsics.unit_rays() if rays is None else rays, direction)
    if not valid.any():
        return np.zeros(valid.shape, np.float32)
    smooth = filtered(depth, valid, median_px)
    residual = np.where(valid, np.abs(np.nan_to_num(depth - smooth)), 0.0).astype(np.float32)
    size = (NOISE_WINDOW_PX, NOISE_WINDOW_PX)
    weight = cv2.blur(valid.astype(np.float32), size)
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.sqrt(np.pi / 2) * cv2.blur(residual, size) / weight
    return np.where(valid, np.nan_to_num(sigma), 0.0).astype(np.float32)


CROP_MARGIN_PX = NOISE_WINDOW_PX + 5  # background ring about the foreground: wider than every filter's reach
CROP_ALIGN_PX = 32  # crop corners on this grid: a head moving a little keeps its crop (and the front test its samples)


def foreground_crop(mask: np.ndarray) -> tuple[slice, slice]:
    """The (rows, cols) slices of the mask's bounding box grown by CROP_MARGIN_PX and aligned to CROP_ALIGN_PX. The
    mask must have a pixel set."""
    return bounding_box(mask, CROP_MARGIN_PX, CROP_ALIGN_PX)


@dataclass(frozen=True, slots=True)
class Candidates:
    """Which foreground pixels may be the nose at all (module docstring); metres, 0 switches a test off."""

    border_margin_m: float = 0.0  # at least this far from the mask border
    front_depth_m: float = 0.0  # at most this far (plus the noise allowance) behind the front-most pixel nearby
    median_px: int = 5  # depth median filter of the front test, pixels (the segmentation's median_px)
    front_noise_factor: float = 0.0  # front test allowance: + this x the pixel's local noise sigma (depth_noise_m)

    @classmethod
    def from_config(cls, detector: DetectorConfig, segmentation: SegmentationConfig) -> Candidates:
        return cls(detector.border_margin_m, detector.front_depth_m, segmentation.median_px,
                   detector.front_noise_factor)

    def keep(self, border_m: np.ndarray, front_gap: np.ndarray, noise_m: np.ndarray | float = 0.0) -> np.ndarray:
        """Bool per pixel from its border distance, front gap and local noise sigma (metres)."""
        ok = np.asarray(border_m) >= self.border_margin_m
        if self.front_depth_m <= 0:
            return ok
        return ok & (np.asarray(front_gap) <= self.front_depth_m + self.front_noise_factor * np.asarray(noise_m))

    def mask(self, foreground: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics,
             direction: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: the candidate pixels of a frame's foreground (direction: the face's, see front_gap_m).

        Only the tests that are on are computed, on the foreground's crop (foreground_crop); `keep` applies them.
        """
        foreground = np.asarray(foreground, dtype=bool)
        out = np.zeros_like(foreground)
        if foreground.any():
            box = foreground_crop(foreground)
            out[box] = self._crop_mask(foreground[box], np.asarray(range_m)[box], intrinsics, box, direction)
        return out

    def pixels(self, foreground: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics,
               direction: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of the candidate pixels, row-major: `mask`'s, found within the crop only."""
        foreground = np.asarray(foreground, dtype=bool)
        if not foreground.any():
            return np.empty(0, np.intp), np.empty(0, np.intp)
        box = foreground_crop(foreground)
        rows, cols = np.nonzero(self._crop_mask(foreground[box], np.asarray(range_m)[box], intrinsics, box, direction))
        return rows + box[0].start, cols + box[1].start

    def _crop_mask(self, foreground: np.ndarray, range_m: np.ndarray, intrinsics: Intrinsics, box: tuple[slice, slice],
                   direction: np.ndarray | None) -> np.ndarray:
        """The candidate pixels of the crop `box` of the image of `intrinsics` (foreground and range_m: the crop's;
        the rays: the whole image's, cut to the box)."""
        off = np.zeros(np.shape(foreground), np.float32)
        rays = intrinsics.unit_rays()[box]
        border = (border_distance_m(foreground, range_m, intrinsics, rays=rays) if self.border_margin_m > 0
                  else off + np.inf)
        front = self.front_depth_m > 0
        gap = (front_gap_m(foreground, range_m, intrinsics, direction, median_px=self.median_px, rays=rays)
               if front else off)
        noise = (depth_noise_m(foreground, range_m, intrinsics, direction, self.median_px, rays=rays)
                 if front and self.front_noise_factor > 0 else off)
        return foreground & self.keep(border, gap, noise)


ALL_FOREGROUND = Candidates()
"""No candidate test: every foreground pixel may be the nose."""


