"""Foreground segmentation as in the paper: adaptive amplitude threshold, then a range percentile.

1. Amplitude: Otsu's threshold on log amplitude over every finite amplitude, floored at 1e-4 of the
   maximum (pixels without a return have amplitude ~0 and count as dark background). Amplitude falls as
   1/r^2, so in log space a near object and a far wall are two compact classes; on linear amplitude
   Otsu splits the broad bright class (a lit face) instead. Foreground = amplitude above it AND a valid
   range (finite, > 0; the driver turns 0xFFFF into NaN). Invalid pixels are never foreground.
2. Range: the paper sets the range threshold "at the top 20th percentile". We read "top" as nearest
   to the camera: keep the pixels of step 1 whose range is at most the `range_percentile` (default 20)
   percentile of their ranges. With a head and torso in view (the renderer's scene, and a user in
   front of the camera) the amplitude step keeps head, neck and shoulders; the nearest 20 % is the
   face, bounded by an iso-range line, so setting the background to the maximum foreground range (FFT
   path) or z to its maximum (NFFT path) gives a smooth transition all along the border — the stated
   purpose of the threshold.
3. Optionally keep only the largest 8-connected region (drops flying pixels and specks that are nearer
   than the face, and islands the range cut leaves).
"""

from __future__ import annotations

import cv2
import numpy as np

from tofd.config import SegmentationConfig

OTSU_BINS = 256
LOG_FLOOR = 1e-4  # amplitudes below this fraction of the maximum count as this fraction


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


def largest_component(mask: np.ndarray) -> np.ndarray:
    """The largest 8-connected region of a bool mask (an all-False mask stays all-False)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8), connectivity=8)
    if count <= 1:
        return mask
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def segment(range_m: np.ndarray, amplitude: np.ndarray, cfg: SegmentationConfig) -> np.ndarray:
    """(H, W) bool foreground mask from a radial range map (metres, NaN/0/inf invalid) and amplitude."""
    range_m = np.asarray(range_m)
    amplitude = np.asarray(amplitude)
    if range_m.shape != amplitude.shape or range_m.ndim != 2:
        raise ValueError(f"range_m {range_m.shape} and amplitude {amplitude.shape} must be equal 2-D shapes")
    finite_amp = np.isfinite(amplitude)
    valid = finite_amp & np.isfinite(range_m) & (range_m > 0)
    if not valid.any():
        return np.zeros(range_m.shape, dtype=bool)
    log_amp = np.log(np.maximum(amplitude, LOG_FLOOR * np.max(amplitude, where=finite_amp, initial=0.0),
                                where=finite_amp, out=np.full(amplitude.shape, np.nan)))
    mask = valid & (log_amp > otsu_threshold(log_amp[finite_amp]))
    if not mask.any():
        return mask
    mask &= range_m <= np.percentile(range_m[mask], cfg.range_percentile)
    return largest_component(mask) if cfg.largest_component else mask
