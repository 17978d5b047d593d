"""Foreground segmentation as in the paper: adaptive amplitude threshold, then an iso-range cut of the head.

1. Amplitude: Otsu's threshold on log amplitude over every finite amplitude, floored at 1e-4 of the
   maximum (pixels without a return have amplitude ~0 and count as dark background). Amplitude falls as
   1/r^2, so in log space a near object and a far wall are two compact classes; on linear amplitude
   Otsu splits the broad bright class (a lit face) instead. Foreground = amplitude above it AND a valid
   range (finite, > 0; the driver turns 0xFFFF into NaN). Invalid pixels are never foreground.
2. Depth. The paper puts a range threshold "at the top 20th percentile" so that there is "a smooth
   transition between foreground and background all along the border": the features set the background
   to the maximum foreground range (FFT path; the NFFT path offsets z to max 0 and its damping pulls the
   field to 0 where there are no points), so the cut must follow an iso-range line of the head for the
   clamped surface to be continuous. Our reading: a cut a fixed depth behind the nearest point, on the depth
   z = range * (z of the pixel's unit ray) that both feature paths filter (on radial range the cut surface
   is a sphere about the camera, which bends 6 mm towards it 7 cm off-axis at 0.35 m and 3 mm at 0.7 m).
   A share of the pixel count (the literal reading) is not that: the share is of whatever the amplitude
   step kept (head alone, or head and shoulders, which grow with proximity), and on our renders it left a
   ragged ~3 cm-deep strip of the face whose border ran 1-2 cm from the nose tip. So:
   - the depth is median-filtered (`median_px` x `median_px`; invalid pixels count as far), so single
     noisy or flying pixels neither fray the cut nor become the nearest point;
   - reference = the `range_percentile` (default 1) percentile of the filtered depths of the step-1
     pixels in the head band: a robust nearest point (the nose tip on a face). Head band (`head_height_m`,
     default 0.18 m; 0 = the whole step-1 foreground): the rows at most that far below the top of the body
     (step-1 pixels within head_height_m in depth of the nearest one; rows converted to metres at that
     depth). The head is the top of a body seen by an upright camera; on a head-and-shoulders view a turned
     and nodded-down head can have a shoulder nearer than its nose, which the plain nearest point would pick;
   - face frame (`plane_iterations` > 0, default 2): depth is measured along the face's viewing direction
     instead of the camera's z axis -- minus the normal of a plane fitted (SVD) to the face front, the head-band
     points within `plane_depth_m` (0.04 m) of the nearest one, refitted along the new direction. A nodding
     head otherwise makes its chin or forehead the nearest point, the cut a slab around it and the nose tip
     sit on the slab's border, where the clamped background dominates its features (the misses at 0.6-0.7 m
     before). The fit follows pitch (a face is flat from brow to chin) better than yaw (it is round across;
     each refit moves the front slab, and the direction, further towards the turned face: estimated against
     true angle over 240 rendered test frames, yaw slope 0.41 / 0.63 / 0.91 after 2 / 4 / 8 fits, pitch
     0.76 / 0.84 / 0.82, residuals 2.4-3.6 deg), and a tilted disc's direction comes back within 0.1 deg
     (tests). More fits did not help robustly (bench/tune_detector.py --grid plane_iter, 3 draws, mean EER
     % FFT range / NFFT range / NFFT range+amplitude: 2 fits 1.1 / 0.7 / 0.6, 4 fits 0.8 / 0.5 / 0.4, 8 fits
     1.3 / 1.0 / 1.0; but with 4 fits the default split's NFFT range EER rose 0.6 -> 1.8 % and 0.4 -> 1.7 % on
     two draws, and holding out each identity in turn NFFT range was 0.8 vs 1.0 % but NFFT range+amplitude
     1.1 vs 0.6 %, 4 vs 2 fits), so 2 stay. Both range feature paths then filter the surface in this frame
     (`Foreground.rotation`): the NFFT features of a tilted disc with a cap equal the frontal ones
     (tests/test_features_nfft.py). Measured (bench/tune_detector.py --grid plane): mean
     leave-one-subject-out EER NFFT range 5.3 -> 3.3 %, FFT range 14.2 -> 9.7 % at rho0 = 30 /m;
   - keep step-1 pixels whose filtered depth is <= reference + `depth_margin_m` (default 0.025 m: the
     nose and the face around it, chosen by cross-validation on the training subjects,
     bench/tune_detector.py). A depth in metres is the same at every distance, unlike a pixel-count share.
3. Clean-up: morphological opening then closing with a `morphology_px` ellipse and holes filled; then
   pixels whose own (unfiltered) depth is invalid or beyond the cut are dropped again -- flying pixels on
   the silhouette and noise spikes that the median hid: the features clamp them to the background value,
   i.e. to the cut, which is the continuous surface the cut is for. Finally, with `nearest_component`,
   only the 8-connected region holding the nearest kept pixel of the head band (the head, not a speck or a
   shoulder that also passed the cut).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from drivers.intrinsics import Intrinsics
from tofd.algorithm.params import SegmentationConfig

OTSU_BINS = 256
LOG_FLOOR = 1e-4  # amplitudes below this fraction of the maximum count as this fraction
FAR_M = 1e4  # metres: invalid pixels' range in the median filter (they never pull a neighbour nearer)


def valid_pixels(range_m: np.ndarray, amplitude: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: pixels with a finite, positive range (and a finite amplitude, if given)."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(range_m) & (range_m > 0)
    return valid if amplitude is None else valid & np.isfinite(amplitude)


def otsu_threshold(values: np.ndarray) -> float:
    """Otsu's threshold of a 1-D sample: the histogram split that maximises the between-class variance."""
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
    _, labels = cv2.connectedComponents((~mask).view(np.uint8), connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return mask | ~np.isin(labels, border)


def amplitude_foreground(amplitude: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Step 1: valid pixels above Otsu's threshold on log amplitude."""
    finite_amp = np.isfinite(amplitude)
    log_amp = np.log(np.maximum(amplitude, LOG_FLOOR * np.max(amplitude, where=finite_amp, initial=0.0),
                                where=finite_amp, out=np.full(amplitude.shape, np.nan)))
    return valid & (log_amp > otsu_threshold(log_amp[finite_amp]))


def filtered(depth_m: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """(H, W) float32 median-filtered depth (size 1: unfiltered), invalid pixels taken as FAR_M."""
    r = np.where(valid, depth_m, FAR_M).astype(np.float32)
    return cv2.medianBlur(r, size) if size > 1 else r


def head_band(mask: np.ndarray, smooth: np.ndarray, cfg: SegmentationConfig, fy: float) -> np.ndarray:
    """The step-1 pixels at most `head_height_m` below the top of the body (all of `mask` if that is 0).

    Body: step-1 pixels whose filtered depth is within `head_height_m` of the nearest one (not a far object
    that passed the amplitude step). Rows are converted to metres at the nearest depth (z / fy per row).
    """
    if cfg.head_height_m <= 0:
        return mask
    nearest = float(np.percentile(smooth[mask], cfg.range_percentile))
    rows = np.flatnonzero((mask & (smooth <= nearest + cfg.head_height_m)).any(axis=1))
    if len(rows) == 0:
        return mask
    last_row = rows[0] + cfg.head_height_m * fy / nearest
    band = mask & (np.arange(mask.shape[0])[:, None] <= last_row)
    return band if band.any() else mask


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


def segment_face(range_m: np.ndarray, amplitude: np.ndarray, cfg: SegmentationConfig,
                 intrinsics: Intrinsics | None = None) -> Foreground:
    """Foreground mask and face frame from a radial range map (metres, NaN/0/inf invalid) and amplitude.

    intrinsics: the camera's, for the depth of each pixel (default: the SR3000 default Intrinsics()).
    """
    range_m = np.asarray(range_m)
    amplitude = np.asarray(amplitude)
    if range_m.shape != amplitude.shape or range_m.ndim != 2:
        raise ValueError(f"range_m {range_m.shape} and amplitude {amplitude.shape} must be equal 2-D shapes")
    rotation = np.eye(3)
    valid = valid_pixels(range_m, amplitude)
    if not valid.any():
        return Foreground(np.zeros(range_m.shape, dtype=bool), rotation)
    intrinsics = intrinsics or Intrinsics()
    if intrinsics.shape != range_m.shape:
        raise ValueError(f"range_m has shape {range_m.shape}, intrinsics {intrinsics.shape}")
    rays = intrinsics.unit_rays()
    ray_z = rays[..., 2]
    depth = range_m * ray_z
    mask = amplitude_foreground(amplitude, valid)
    smooth = filtered(depth, valid, cfg.median_px)
    mask &= smooth < FAR_M
    if not mask.any():
        return Foreground(mask, rotation)
    head = head_band(mask, smooth, cfg, intrinsics.fy)
    if cfg.plane_iterations > 0:
        direction = face_direction(rays[head] * (smooth[head] / ray_z[head])[:, None], cfg)
        rotation = rotation_to_z(direction)
        along = rays @ direction  # range -> distance along the face's viewing direction
        smooth = smooth * (along / ray_z)
        with np.errstate(invalid="ignore"):
            depth = range_m * along
    reference = float(np.percentile(smooth[head], cfg.range_percentile))
    cut = reference + cfg.depth_margin_m
    mask &= smooth <= cut
    if cfg.morphology_px > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.morphology_px, cfg.morphology_px))
        m = cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_OPEN, kernel)
        mask = cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel).view(bool)
    with np.errstate(invalid="ignore"):
        mask = fill_holes(mask) & valid & (depth <= cut)
    if cfg.nearest_component and (mask & head).any():
        nearest = int(np.argmin(np.where(mask & head, smooth, np.inf)))
        mask = component_at(mask, *divmod(nearest, mask.shape[1]))
    return Foreground(mask, rotation)
