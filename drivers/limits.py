"""The one rule on image sizes and lens calibrations that every source, recording, config and library function
applies before it spends memory or arithmetic on them.

No time-of-flight camera sends more than about a megapixel (Azure Kinect's widest unbinned mode is 1024 x 1024;
the SR3000 176 x 144), so a larger image is damage or an attack: refused as a data error, never allocated. A
calibration must be finite, with focal lengths between FOCAL_RANGE[0] and FOCAL_RANGE[1] times the image's longer
side (from a fisheye's half-sphere to a telephoto) and the principal point within an image size of the image.
"""

from __future__ import annotations

import math
import numbers

MAX_IMAGE_SIDE = 4096
"""Widest or tallest image accepted, pixels."""
MAX_IMAGE_PIXELS = 1 << 21
"""Most pixels in one image (2 Mpx: twice the largest time-of-flight mode)."""
FOCAL_RANGE = (0.01, 1000.0)
"""Focal lengths accepted, as multiples of the image's longer side."""


def _real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def image_size_problem(width: object, height: object) -> str | None:
    """Why an image of `width` x `height` pixels is refused, or None (positive integers within the caps)."""
    if not (isinstance(width, numbers.Integral) and isinstance(height, numbers.Integral)
            and not isinstance(width, bool) and not isinstance(height, bool) and int(width) > 0 and int(height) > 0):
        return f"image size {width!r} x {height!r}: expected positive whole pixels"
    if max(int(width), int(height)) > MAX_IMAGE_SIDE or int(width) * int(height) > MAX_IMAGE_PIXELS:
        return (f"image size {width} x {height}: larger than any time-of-flight camera sends "
                f"(at most {MAX_IMAGE_SIDE} a side and {MAX_IMAGE_PIXELS} pixels)")
    return None


def calibration_problem(width: int, height: int, fx: object, fy: object, cx: object, cy: object) -> str | None:
    """Why a pinhole calibration (pixels) of a `width` x `height` image (already within the caps) is refused, or
    None; the message starts with the field's name ("fx: ...")."""
    side = max(width, height)
    low, high = FOCAL_RANGE[0] * side, FOCAL_RANGE[1] * side
    for name, value in (("fx", fx), ("fy", fy)):
        if not (_real(value) and low <= value <= high):  # type: ignore[operator]
            return f"{name}: expected a finite focal length in {low:g}..{high:g} pixels, got {value!r}"
    for name, value, length in (("cx", cx, width), ("cy", cy, height)):
        if not (_real(value) and -length <= value <= 2 * length):  # type: ignore[operator]
            return f"{name}: expected a finite principal point near the image ({-length}..{2 * length}), got {value!r}"
    return None


def check_image_shape(shape: tuple[int, ...], what: str) -> None:
    """ValueError naming `what` when an array of `shape` (..., H, W) has images beyond the caps."""
    if len(shape) < 2:
        raise ValueError(f"{what}: expected (..., H, W) images, got shape {shape}")
    if (problem := image_size_problem(shape[-1], shape[-2])) is not None:
        raise ValueError(f"{what}: {problem}")
