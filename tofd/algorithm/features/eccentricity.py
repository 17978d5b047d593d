"""The result type shared by both feature paths."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    def empty(cls, shape: tuple[int, int], iterations: int = 0, residual: float = float("nan")) -> Eccentricities:
        """All-NaN maps (no foreground)."""
        return cls(np.full(shape, np.nan, np.float32), np.full(shape, np.nan, np.float32), iterations, residual)
