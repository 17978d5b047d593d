"""Limits on what a recording (or any input that describes frames) may claim before tofd trusts it.

No time-of-flight camera sends more than about a megapixel (Azure Kinect's widest unbinned mode is 1024 x 1024;
the SR3000 176 x 144), so anything beyond these caps is damage or an attack, refused before memory is spent on
it: a recording, a dataset or a config that declares it is a data (or config) error, never an allocation.
"""

from __future__ import annotations

import math

from tofd.drivers.intrinsics import Intrinsics

MAX_IMAGE_SIDE = 4096
"""Widest or tallest image accepted, pixels."""
MAX_IMAGE_PIXELS = 1 << 21
"""Most pixels in one image (2 Mpx: twice the largest time-of-flight mode)."""
FRAME_OVERHEAD_BYTES = 256 << 10
"""Bytes of a frame's chunk besides its two float32-or-narrower planes (header, calibration, record framing)."""
MAX_CHUNK_BYTES = 2 * 4 * MAX_IMAGE_PIXELS + FRAME_OVERHEAD_BYTES
"""Largest decompressed chunk (one frame of the largest accepted image, both planes float32), bytes (~16 MiB)."""
MAX_RECORD_BYTES = MAX_CHUNK_BYTES
"""Largest top-level record accepted (a chunk is compressed, so never larger than its decompressed records)."""
MAX_CHUNK_RECORDS = 64
"""Most records in one chunk (tofd writes one frame per chunk: four messages, or one in format 1)."""
MAX_METADATA_BYTES = 64 << 10
"""Largest metadata record (a few dozen short strings), bytes."""
MAX_ATTACHMENT_BYTES = 1 << 20
"""Largest attachment (the service config as JSON is a few kB), bytes."""
MAX_SUMMARY_BYTES = 64 << 20
"""Largest MCAP summary section read for the frame count (about 100 bytes of chunk index per frame), bytes."""


def image_size_problem(width: object, height: object) -> str | None:
    """Why an image of `width` x `height` pixels is refused, or None (positive integers within the caps)."""
    if not (isinstance(width, int) and isinstance(height, int) and width > 0 and height > 0):
        return f"image size {width!r} x {height!r}: expected positive whole pixels"
    if max(width, height) > MAX_IMAGE_SIDE or width * height > MAX_IMAGE_PIXELS:
        return (f"image size {width} x {height}: larger than any time-of-flight camera sends "
                f"(at most {MAX_IMAGE_SIDE} a side and {MAX_IMAGE_PIXELS} pixels)")
    return None


def intrinsics_problem(intr: Intrinsics) -> str | None:
    """Why intrinsics are refused, or None: image size within the caps, focal lengths finite and > 0, the
    principal point finite and within a few image widths of the image."""
    if (problem := image_size_problem(intr.width, intr.height)) is not None:
        return problem
    for name in ("fx", "fy"):
        value = getattr(intr, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            return f"intrinsics {name} = {value!r}: expected a finite focal length > 0 (pixels)"
    for name, side in (("cx", intr.width), ("cy", intr.height)):
        value = getattr(intr, name)
        if not (isinstance(value, int | float) and math.isfinite(value) and -side <= value <= 2 * side):
            return f"intrinsics {name} = {value!r}: expected a finite principal point near the image (0..{side})"
    return None


def frame_chunk_limit(intr: Intrinsics) -> int:
    """Largest decompressed chunk a frame of these (checked) intrinsics can need, bytes."""
    return 2 * 4 * intr.width * intr.height + FRAME_OVERHEAD_BYTES
