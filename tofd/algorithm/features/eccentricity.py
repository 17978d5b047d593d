"""The result type shared by both feature paths."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MapsOut = tuple[np.ndarray, np.ndarray]  # (H, W) float32 arrays to write eps0, eps2 into (e.g. shared memory)


@dataclass(slots=True)
class Eccentricities:
    """Generalized eccentricities of one frame.

    eps0, eps2: (H, W) float32 images (metres^2 for range features), NaN outside the foreground, at holes (range
    NaN, inf or <= 0) and, for NFFT, at foreground points outside the patch. iterations: CG iterations (0 for
    FFT); residual: final relative CG residual (NaN for FFT or an empty foreground).
    """

    eps0: np.ndarray
    eps2: np.ndarray
    iterations: int = 0
    residual: float = float("nan")

    @classmethod
    def empty(cls, shape: tuple[int, int], iterations: int = 0, residual: float = float("nan"),
              out: MapsOut | None = None) -> Eccentricities:
        """All-NaN maps (no foreground): new arrays, or the arrays of `out` filled with NaN."""
        if out is None:
            return cls(np.full(shape, np.nan, np.float32), np.full(shape, np.nan, np.float32), iterations, residual)
        for a in out:
            if a.shape != shape or a.dtype != np.float32 or not a.flags.c_contiguous:
                raise ValueError(f"out: maps must be C-contiguous float32 arrays of shape {shape}, got {a.dtype} "
                                 f"{a.shape}")
            a.fill(np.nan)
        return cls(out[0], out[1], iterations, residual)
