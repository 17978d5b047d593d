"""glibc heap settings for processes that handle frames: freed frame-sized arrays stay on the heap for reuse.

By default glibc returns the heap's free top above 128 KiB to the kernel and serves large allocations with fresh
mmaps (from 128 KiB up where the threshold is pinned, as Dask's nanny does with MALLOC_TRIM_THRESHOLD_), so each
frame's (H, W) arrays and temporaries page-fault again on first touch. The settings keep that memory: RSS
holds at the working set's high-water mark.
"""

from __future__ import annotations

import ctypes

MMAP_THRESHOLD_BYTES = 64 << 20  # only allocations this large get their own mapping
TRIM_THRESHOLD_BYTES = 128 << 20  # free heap top kept before any is returned to the kernel
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters


def keep_arrays_on_the_heap() -> bool:
    """Apply the settings to this process; False where the C library is not glibc (nothing changes)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                    and libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False
