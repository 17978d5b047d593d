"""Process-wide settings of the processes tofd starts to compute frames (pipeline workers, the viewer process,
batch tasks, evaluation workers) and of the service's own process: applied by those processes' entry points,
never by library code on arrays, because they change the whole process.

One thread per process in the numerical libraries: results do not depend on thread scheduling, and N processes
use N cores. finufft plans and scipy.fft calls take nthreads=1 / workers=1 at each call; OpenMP and BLAS read
THREAD_ENV when they load (so it must be in a process's environment before it starts, or before they are
imported); OpenCV keeps its own pool, sized by cv2.setNumThreads.

glibc heap settings: by default glibc returns the heap's free top above 128 KiB to the kernel and serves large
allocations with fresh mmaps (from 128 KiB up where the threshold is pinned, as Dask's nanny does with
MALLOC_TRIM_THRESHOLD_), so each frame's (H, W) arrays and temporaries page-fault again on first touch.
keep_arrays_on_the_heap keeps that memory: RSS holds at the working set's high-water mark.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Iterator
from contextlib import contextmanager

THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
MMAP_THRESHOLD_BYTES = 64 << 20  # only allocations this large get their own mapping
TRIM_THRESHOLD_BYTES = 128 << 20  # free heap top kept before any is returned to the kernel
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters


def keep_arrays_on_the_heap() -> bool:
    """Apply the heap settings to this process; False where the C library is not glibc (nothing changes)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
                    and libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    except (OSError, AttributeError):
        return False


def use_one_thread() -> None:
    """Put THREAD_ENV into this process's environment (for libraries loaded later and for child processes) and
    make OpenCV single-threaded."""
    os.environ.update(THREAD_ENV)
    import cv2

    cv2.setNumThreads(1)


def prepare_compute_process() -> None:
    """Set up a process that computes every frame's features (pipeline worker, batch task, evaluation worker):
    one thread and frame arrays kept on the heap."""
    use_one_thread()
    keep_arrays_on_the_heap()


def prepare_service_process() -> None:
    """Set up the service's own process (tofd run, tofd replay): it copies every frame in and its maps out."""
    keep_arrays_on_the_heap()


@contextmanager
def child_environment(values: dict[str, str]) -> Iterator[None]:
    """os.environ with `values` set while child processes start (they copy the environment then); this process's
    environment is restored after."""
    before = {key: os.environ.get(key) for key in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in before.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
