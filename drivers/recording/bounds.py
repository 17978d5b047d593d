"""Limits on what a tofd recording may claim before tofd trusts it: record, chunk, metadata, attachment and summary
sizes, derived from the image caps every input shares (tofd.drivers.limits).
"""

from __future__ import annotations

from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.limits import MAX_IMAGE_PIXELS

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


def frame_chunk_limit(intr: Intrinsics) -> int:
    """Largest decompressed chunk a frame of these (checked) intrinsics can need, bytes."""
    return 2 * 4 * intr.width * intr.height + FRAME_OVERHEAD_BYTES
