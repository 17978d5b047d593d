"""scipy's pocketfft engine (the binding behind scipy.fft) with named arguments: the one module that calls it.

The NFFT path's CG step calls the engine directly because it writes into given arrays and skips scipy.fft's
per-call dispatch. The engine is private to scipy: these wrappers fix the meaning of its positional flags, and
tests/test_pocketfft.py pins them against numpy.fft for the scipy versions pyproject.toml allows.

`scale` is the engine's normalisation code: 0 none, 1 divide by sqrt(n), 2 divide by n (n: the product of the
transformed axes' lengths, in the real domain for c2r / r2c). Transforms run on one thread (the compute
processes' rule, tofd.process_setup).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.fft._pocketfft import pypocketfft as _engine

Scale = Literal[0, 1, 2]


def c2c(data: np.ndarray, *, axes: tuple[int, ...], forward: bool, out: np.ndarray, scale: Scale = 0) -> np.ndarray:
    """Complex-to-complex FFT of `data` over `axes` into `out` (same shape and dtype); returns `out`."""
    result: np.ndarray = _engine.c2c(data, axes, forward, scale, out, 1)
    return result


def c2r(half: np.ndarray, *, axes: tuple[int, ...], last_size: int, out: np.ndarray, scale: Scale = 0) -> np.ndarray:
    """Inverse FFT of a Hermitian half spectrum (last axis of `axes` holds last_size // 2 + 1 values) to real
    `out`, whose last transformed axis has `last_size` points; returns `out`."""
    result: np.ndarray = _engine.c2r(half, axes, last_size, False, scale, out, 1)
    return result


def r2c(data: np.ndarray, *, axes: tuple[int, ...], out: np.ndarray, scale: Scale = 0) -> np.ndarray:
    """Forward FFT of real `data` over `axes` into the half spectrum `out` (the last axis of `axes` shortened to
    n // 2 + 1); returns `out`."""
    result: np.ndarray = _engine.r2c(data, axes, True, scale, out, 1)
    return result
