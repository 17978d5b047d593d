"""Foreground segmentation: an adaptive amplitude threshold, then a range cut along an iso-depth line of the head.

1. Amplitude: Otsu's threshold on the log amplitude of the pixels with a range (floored at 1e-4 of their maximum;
   the dark pixels outside a wide lens's image circle would split the histogram); in log space a near object and
   a far wall are two compact classes, since amplitude falls as 1/r^2. Foreground = above it and `valid_pixels`.
2. Depth: the paper's range threshold at "the top 20th percentile", read as a cut a fixed depth behind the
   nearest point, so that the background clamped to the cut joins the surface smoothly all along the border:
   - depth z = range * (z of the pixel's unit ray), median-filtered over `median_px` (invalid pixels count as far);
   - reference = the `range_percentile` percentile of the filtered depths inside the head band (`head_height_m`
     below the top of the body), a robust nearest point;
   - with `plane_iterations` > 0 depth is measured along the face's viewing direction (minus the normal of a
     plane fitted by SVD to the face front within `plane_depth_m`), so a nodding head keeps its nose tip inside
     the cut; both range feature paths filter the surface in this frame (`Foreground.rotation`);
   - a pixel more than `head_height_m` behind the nearest one in camera depth (a wall off to the side of a wide
     field of view, which a tilted face frame brings nearer) is never the reference nor the nearest pixel;
   - keep pixels whose filtered depth <= reference + `depth_margin_m`.
3. Clean-up: opening and closing with a `morphology_px` ellipse, holes filled, pixels whose own depth is invalid
   or beyond the cut dropped again (flying pixels), and with `nearest_component` only the 8-connected region
   holding the nearest pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tofd.algorithm.params import SegmentationConfig
from tofd.drivers.intrinsics import Intrinsics

OTSU_BINS = 256
LOG_FLOOR = 1e-4  # amplitudes below this fraction of the maximum count as this fraction
FAR_M = 1e4  # metres: invalid pixels' range in the median filter (they never pull a neighbour nearer)


def valid_pixels(range_m: np.ndarray, amplitude: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels with a finite, positive range (and a finite amplitude, if given)."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(range_m) & (range_m > 0)
    return valid if amplitude is None else valid & np.isfinite(amplitude)


def otsu_threshold(values: np.ndarray) -> float:
    """Otsu's threshold of a 1-D sample: the histogram split that maximises the between-class variance; a sample
    of one value (or none) has no split, and its threshold is that value (inf for none): nothing lies above it."""
    if values.size == 0:
        return float("inf")
    if np.min(values) == np.max(values):
        return float(values.flat[0])
    hist, edges = np.histogram(values, bins=OTSU_BINS)
    centres = (edges[:-1] + edges[1:]) / 2
    w0 = np.cumsum(hist, dtype=np.float64)
    w1 = w0[-1] - w0
    m0 = np.cumsum(hist * centres)
    with np.errstate(divide="ignore", invalid="ignore"):
        between = w0 * w1 * (m0 / w0 - (m0[-1] - m0) / w1) ** 2
    return float(edges[int(np.nanargmax(between[:-1])) + 1])


def component_at(mask: np.ndarray, row: int, col: int) -> np.ndarray:
    """The 8-connected region of a bool mask that holds pixel (row, col) (all False if that pixel is not set)."""
    _, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    label = labels[row, col]
    return (labels == label) if label else np.zeros_like(mask)


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask with every background region that does not touch the image border set."""
    count, labels = cv2.connectedComponents((~mask).view(np.uint8), connectivity=4)
    outside = np.zeros(count, bool)  # per label: touches the border (label 0, the mask itself, stays as it is)
    outside[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = True
    return mask | ~outside[labels]


def amplitude_foreground(amplitude: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Step 1: valid pixels above Otsu's threshold on the log amplitude of the valid pixels (a pixel without a
    range, such as the dark corners outside a wide lens's image circle, never splits the histogram)."""
    peak = np.max(amplitude, where=valid, initial=0.0)
    if not peak > 0:  # no return anywhere (all zero, negative or non-finite): nothing is foreground
        return np.zeros(amplitude.shape, bool)
    log_amp = np.log(np.maximum(amplitude, LOG_FLOOR * peak, where=valid, out=np.full(amplitude.shape, np.nan)))
    return valid & (log_amp > otsu_threshold(log_amp[valid]))


def filtered(depth_m: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """(H, W) float32 median-filtered depth (size 1: unfiltered), invalid pixels taken as FAR_M."""
    r = np.where(valid, depth_m, FAR_M).astype(np.float32)
    return cv2.medianBlur(r, size) if size > 1 else r


def head_band(mask: np.ndarray, smooth: np.ndarray, cfg: SegmentationConfig,
              fy: float) -> tuple[np.ndarray, np.ndarray]:
    """The step-1 pixels at most `head_height_m` below the top of the body, and the body's pixels among them
    (both all of `mask` if that is 0).

    Body: step-1 pixels whose filtered depth is within `head_height_m` of the nearest one (not a far object
    that passed the amplitude step); the nearest is the `range_percentile` percentile of the step-1 depths, or of
    those more than `head_height_m` in front of it where there are any (an object too small to move the
    percentile, such as a head before a wide field of view's lit wall). Rows are converted to metres at the
    nearest depth (z / fy per row).
    """
    if cfg.head_height_m <= 0:
        return mask, mask
    nearest = float(np.percentile(smooth[mask], cfg.range_percentile))
    front = mask & (smooth < nearest - cfg.head_height_m)
    if front.any():  # a small object well in front of the rest (specks are gone in the median filter)
        nearest = float(np.percentile(smooth[front], cfg.range_percentile))
    body = mask & (smooth <= nearest + cfg.head_height_m)
    rows = np.flatnonzero(body.any(axis=1))
    if len(rows) == 0:
        return mask, mask
    last_row = rows[0] + cfg.head_height_m * fy / nearest
    band = mask & (np.arange(mask.shape[0])[:, None] <= last_row)
    return (band, band & body) if band.any() else (mask, body)


@dataclass(frozen=True, slots=True)
class Foreground:
    """A frame's segmentation: the foreground mask and the face frame its depth cut was made in."""

    mask: np.ndarray  # (H, W) bool
    rotation: np.ndarray  # (3, 3) camera -> face frame; row 2 = unit viewing direction of the face (identity: camera z)


def rotation_to_z(direction: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking the unit vector `direction` (z component > 0) onto +z."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(direction, z)
    s2 = float(axis @ axis)
    if s2 < 1e-18:
        return np.eye(3)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + k + k @ k * ((1.0 - float(direction @ z)) / s2)


def face_direction(points: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """Unit viewing direction (z > 0) of the face: minus the normal of a plane fitted to its front.

    Front: the points within `plane_depth_m` of the nearest (`range_percentile`) along the current
    direction, starting from the camera's z axis; the plane is refitted `plane_iterations` times. The tilt
    from z is limited to `plane_max_tilt_deg`.
    """
    direction = np.array([0.0, 0.0, 1.0])
    max_tilt = np.radians(cfg.plane_max_tilt_deg)
    for _ in range(cfg.plane_iterations):
        d = points @ direction
        front = points[d <= np.percentile(d, cfg.range_percentile) + cfg.plane_depth_m]
        if len(front) < 3:
            break
        normal = np.linalg.svd(front - front.mean(axis=0), full_matrices=False)[2][2]
        normal *= np.sign(normal[2]) or 1.0
        tilt = np.arccos(np.clip(normal[2], -1.0, 1.0))
        if tilt > max_tilt:  # keep the azimuth, limit the angle
            lateral = normal[:2] / np.linalg.norm(normal[:2])
            normal = np.array([*(np.sin(max_tilt) * lateral), np.cos(max_tilt)])
        direction = normal
    return direction


def segment(range_m: np.ndarray, amplitude: np.ndarray, cfg: SegmentationConfig,
            intrinsics: Intrinsics | None = None) -> np.ndarray:
    """(H, W) bool foreground mask from a radial range map (metres, NaN/0/inf invalid) and amplitude."""
    return segment_face(range_m, amplitude, cfg, intrinsics).mask


REFERENCE_FOCAL_PX = Intrinsics().fx  # pixels: the camera whose pixel sizes the config's *_px settings mean (SR3000)


def coarse_stride(intrinsics: Intrinsics) -> int:
    """Decimation that brings the camera's pixel footprint (range / focal length) nearest the reference camera's:
    the segmentation runs on every stride-th pixel, so its pixel-sized filters mean the same metres on every camera
    (1 on the SR3000)."""
    return max(1, int(min(intrinsics.fx, intrinsics.fy) / REFERENCE_FOCAL_PX + 0.5))


def decimated(intrinsics: Intrinsics, stride: int) -> Intrinsics:
    """The intrinsics of the image of every stride-th pixel (rows and columns 0, stride, 2 stride, ...)."""
    return Intrinsics(-(-intrinsics.width // stride), -(-intrinsics.height // stride), intrinsics.fx / stride,
                      intrinsics.fy / stride, intrinsics.cx / stride, intrinsics.cy / stride)


def nearest_samples(length: int, samples: int, stride: int) -> np.ndarray:
    """(length,) index of the sample nearest each pixel along an axis sampled at every stride-th pixel."""
    return np.minimum((np.arange(length) + stride // 2) // stride, samples - 1)


def upsampled(coarse: np.ndarray, shape: tuple[int, int], stride: int) -> np.ndarray:
    """An image of every stride-th pixel brought back to `shape` by nearest neighbour (each pixel takes the value
    of the sampled pixel nearest it)."""
    rows = nearest_samples(shape[0], coarse.shape[0], stride)
    cols = nearest_samples(shape[1], coarse.shape[1], stride)
    return coarse[rows[:, None], cols[None, :]]


def upsampled_box(coarse: np.ndarray, shape: tuple[int, int], stride: int
                  ) -> tuple[tuple[slice, slice], np.ndarray]:
    """bounding_box of upsampled(coarse, shape, stride) and that image within it, without upsampling the rest (a
    bool mask with a pixel set): each pixel's nearest sample is monotone in the pixel, so the box's rows are those
    whose nearest sample row lies in the coarse mask's box, and likewise the columns."""
    cbox = bounding_box(coarse)
    index, box = [], []
    for axis, (length, cut) in enumerate(zip(shape, cbox, strict=True)):
        nearest = nearest_samples(length, coarse.shape[axis], stride)
        lo, hi = np.searchsorted(nearest, cut.start, "left"), np.searchsorted(nearest, cut.stop - 1, "right")
        box.append(slice(int(lo), int(hi)))
        index.append(nearest[lo:hi])
    return (box[0], box[1]), coarse[index[0][:, None], index[1][None, :]]


def foreground_box(mask: np.ndarray) -> tuple[slice, slice]:
    """(rows, cols) slices of a bool mask's bounding box; empty slices (0:0) for an empty mask."""
    return bounding_box(mask) if mask.any() else (slice(0, 0), slice(0, 0))


def bounding_box(mask: np.ndarray, margin_px: int = 0, align_px: int = 1) -> tuple[slice, slice]:
    """(rows, cols) slices of a mask's bounding box grown by margin_px, corners on an align_px grid, clipped to the
    image. The mask must have a pixel set."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    a = align_px
    r0, c0 = max(rows[0] - margin_px, 0) // a * a, max(cols[0] - margin_px, 0) // a * a
    r1, c1 = min(-(-(rows[-1] + 1 + margin_px) // a) * a, h), min(-(-(cols[-1] + 1 + margin_px) // a) * a, w)
    return slice(int(r0), int(r1)), slice(int(c0), int(c1))


def segment_face(range_m: np.ndarray, amplitude: np.ndarray, cfg: SegmentationConfig,
                 intrinsics: Intrinsics | None = None) -> Foreground:
    """Foreground mask and face frame from a radial range map (metres, NaN/0/inf invalid) and amplitude.

    intrinsics: the camera's, for the depth of each pixel (default: the SR3000 default Intrinsics()). A camera of
    finer pixels (coarse_stride > 1) is segmented on every stride-th pixel; the mask is brought back to every pixel
    by nearest neighbour and each pixel's own validity and depth cut (step 3's flying-pixel test) applied again.
    """
    range_m = np.asarray(range_m)
    amplitude = np.asarray(amplitude)
    if range_m.shape != amplitude.shape or range_m.ndim != 2:
        raise ValueError(f"range_m {range_m.shape} and amplitude {amplitude.shape} must be equal 2-D shapes")
    intrinsics = intrinsics or Intrinsics()
    if intrinsics.shape != range_m.shape:
        raise ValueError(f"range_m has shape {range_m.shape}, intrinsics {intrinsics.shape}")
    stride = coarse_stride(intrinsics)
    if stride == 1:
        mask, rotation, _ = _segment(range_m, amplitude, cfg, intrinsics)
        return Foreground(mask, rotation)
    coarse, rotation, cut = _segment(np.ascontiguousarray(range_m[::stride, ::stride]),  # strided reads once
                                     np.ascontiguousarray(amplitude[::stride, ::stride]), cfg,
                                     decimated(intrinsics, stride))
    mask = np.zeros(range_m.shape, dtype=bool)
    if not coarse.any():
        return Foreground(mask, rotation)
    box, near = upsampled_box(coarse, range_m.shape, stride)
    with np.errstate(invalid="ignore"):
        depth = range_m[box] * (intrinsics.unit_rays()[box] @ rotation[2]).astype(np.float32)
        mask[box] = near & valid_pixels(range_m[box], amplitude[box]) & (depth <= cut)
    return Foreground(mask, rotation)


def _segment(range_m: np.ndarray, amplitude: np.ndarray, cfg: SegmentationConfig,
             intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray, float]:
    """Steps 1-3 of the module docstring at the image's own resolution: (mask, rotation, depth cut in metres)."""
    rotation = np.eye(3)
    valid = valid_pixels(range_m, amplitude)
    if not valid.any():
        return np.zeros(range_m.shape, dtype=bool), rotation, np.inf
    rays = intrinsics.unit_rays()
    ray_z = rays[..., 2]
    depth = range_m * ray_z
    mask = amplitude_foreground(amplitude, valid)
    smooth = filtered(depth, valid, cfg.median_px)
    mask &= smooth < FAR_M
    if not mask.any():
        return mask, rotation, np.inf
    head, body = head_band(mask, smooth, cfg, intrinsics.fy)
    if cfg.plane_iterations > 0:
        direction = face_direction(rays[head] * (smooth[head] / ray_z[head])[:, None], cfg)
        rotation = rotation_to_z(direction)
        along = rays @ direction  # range -> distance along the face's viewing direction
        smooth = smooth * (along / ray_z)
        with np.errstate(invalid="ignore"):
            depth = range_m * along
    reference = float(np.percentile(smooth[head], cfg.range_percentile))
    if (smooth[head & ~body] <= reference).any():  # along a tilted face frame, a far wall off to the side came nearer
        reference = float(np.percentile(smooth[body], cfg.range_percentile))
    cut = reference + cfg.depth_margin_m
    mask &= smooth <= cut
    if cfg.morphology_px > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.morphology_px, cfg.morphology_px))
        m = cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_OPEN, kernel)
        mask = cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel).view(bool)
    with np.errstate(invalid="ignore"):
        mask = fill_holes(mask) & valid & (depth <= cut)
    if cfg.nearest_component and (mask & head).any():
        nearest = int(np.argmin(np.where(mask & (body if (mask & body).any() else head), smooth, np.inf)))
        mask = component_at(mask, *divmod(nearest, mask.shape[1]))
    return mask, rotation, cut
