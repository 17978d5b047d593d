"""One thread per process in the algorithm's numerical libraries, the rule of every process that computes features
(pipeline workers, batch tasks, evaluation workers): results do not depend on thread scheduling, and N processes
use N cores.

finufft plans and scipy.fft calls take nthreads=1 / workers=1 at each call; OpenMP and BLAS read THREAD_ENV when
they load (so it must be in a process's environment before it starts, or before they are imported); OpenCV keeps
its own pool, sized by cv2.setNumThreads.
"""

from __future__ import annotations

import os

from tofd.algorithm.heap import keep_arrays_on_the_heap

THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def use_one_thread() -> None:
    """Put THREAD_ENV into this process's environment (for libraries loaded later and for child processes) and
    make OpenCV single-threaded."""
    os.environ.update(THREAD_ENV)
    import cv2

    cv2.setNumThreads(1)


def prepare_compute_process() -> None:
    """Set up a process that computes every frame's features (pipeline worker, batch task): one thread
    (use_one_thread) and frame arrays kept on the heap (tofd.algorithm.heap)."""
    use_one_thread()
    keep_arrays_on_the_heap()
