"""The result type shared by both feature paths."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

MapsOut = tuple[np.ndarray, np.ndarray]  # (H, W) float32 or float64 arrays to write eps0, eps2 into (shared memory)


@dataclass(slots=True)
class Eccentricities:
    """Generalized eccentricities of one frame.

    eps0, eps2: (H, W) images (metres^2 for range features), float32 unless written into float64 `out` arrays (the
    public functions' results), NaN outside the foreground, at holes (range NaN, inf or <= 0) and, for NFFT, at
    foreground points outside the patch. iterations: CG iterations (0 for FFT); residual: final relative CG residual
    (NaN for FFT or an empty foreground). They unpack: ``eps0, eps2 = maps``.
    """

    eps0: np.ndarray
    eps2: np.ndarray
    iterations: int = 0
    residual: float = float("nan")

    def __iter__(self) -> Iterator[np.ndarray]:
        """eps0, eps2: the maps unpack, ``eps0, eps2 = tofd.eccentricities(...)``."""
        return iter((self.eps0, self.eps2))

    @classmethod
    def empty(cls, shape: tuple[int, int], iterations: int = 0, residual: float = float("nan"),
              out: MapsOut | None = None) -> Eccentricities:
        """All-NaN maps (no foreground): new arrays, or the arrays of `out` filled with NaN."""
        if out is None:
            return cls(np.full(shape, np.nan, np.float32), np.full(shape, np.nan, np.float32), iterations, residual)
        for a in out:
            if a.shape != shape or a.dtype not in (np.float32, np.float64) or a.dtype != out[0].dtype \
                    or not a.flags.c_contiguous:
                raise ValueError(f"out: maps must be C-contiguous float32 or float64 arrays of one dtype and shape "
                                 f"{shape}, got {a.dtype} {a.shape}")
            a.fill(np.nan)
        return cls(out[0], out[1], iterations, residual)
