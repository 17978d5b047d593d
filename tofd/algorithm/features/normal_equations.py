"""The NFFT path's damped normal equations (A^H A + lambda I) f = A^H z, solved by conjugate gradients.

Unknowns: the Fourier coefficients f_k of a real field on the N x N mode grid k in [-N/2, N/2)^2, stored as
the compact half spectrum (N - 1, N/2) complex: rows ky = 0 .. N/2 - 1, -N/2 + 1 .. -1 (FFT order without the
unpaired Nyquist row), columns kx = 0 .. N/2 - 1. The other half follows by Hermitian symmetry.

Operator. A^H A is Toeplitz, (A^H A f)_k = sum_l K_{k-l} f_l with K_m = sum_j exp(-2 pi i m.x_j), so it is
applied as a circulant convolution on the 2N x 2N grid: one real FFT pair of size 2N, pruned to the modes
that hold data (the inverse transform along ky runs only over the N/2 columns kx = 0 .. N/2 - 1 that are
nonzero, the forward one only over the N/2 columns that are kept), which saves a quarter of the work.

Stopping. CG stops when the residual weighted by A(rho) (the filters' band) falls below the tolerance
relative to the weighted right-hand side: smooth surfaces put most of A^H z at low frequencies that the
filters ignore, and the plain residual stopped a sphere with eps0 off by 15 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from scipy.linalg.blas import get_blas_funcs


@dataclass(frozen=True, slots=True)
class Solution:
    """f: (N - 1, N/2) compact half spectrum; iterations; residual: final relative band-weighted residual."""

    f: np.ndarray
    iterations: int
    residual: float


class PrunedRealFFT:
    """Real FFTs of size 2N x 2N between a compact half spectrum (N - 1, N/2) and a (2N, 2N) real field."""

    def __init__(self, n: int, dtype: type[np.complexfloating]):
        self.h, self.size = n // 2, 2 * n
        self._columns = np.zeros((2 * n, n // 2), dtype)  # the half spectrum's columns, zero-padded in ky

    def to_space(self, half: np.ndarray) -> np.ndarray:
        """(2N, 2N) real field whose spectrum is `half`, zero elsewhere (unnormalised inverse transform)."""
        h, cols = self.h, self._columns
        cols[:h] = half[:h]
        cols[self.size - h + 1:] = half[h:]
        return sfft.irfft(sfft.ifft(cols, axis=0, workers=1), n=self.size, axis=1, workers=1)

    def from_space(self, field: np.ndarray, out: np.ndarray) -> np.ndarray:
        """out = the compact half of field's spectrum (forward transform)."""
        h = self.h
        spec = sfft.fft(sfft.rfft(field, axis=1, workers=1)[:, :h], axis=0, workers=1)
        out[:h] = spec[:h]
        out[h:] = spec[self.size - h + 1:]
        return out


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """Re <a, b> of the full Hermitian spectra, from their compact halves (kx > 0 counted twice)."""
    return 2.0 * np.vdot(a, b).real - np.vdot(a[:, 0], b[:, 0]).real


class DampedNormalEquations:
    """A^H A + lambda I for one frame's points, from K on the 2N x 2N grid (finufft type 1, modeord=1)."""

    def __init__(self, kernel: np.ndarray, lam: float, n: int, real: type[np.floating],
                 complex_: type[np.complexfloating]):
        self.lam = lam
        self._fft = PrunedRealFFT(n, complex_)
        half = kernel[:, : n + 1].copy()
        half[n, :] = 0  # the unpaired -N row and column never enter (A^H A f)_k for |k| < N/2
        half[:, n] = 0
        self._circulant = (sfft.irfft2(half, s=(2 * n, 2 * n), workers=1) * float(4 * n * n)).astype(real)
        self._axpy = get_blas_funcs("axpy", dtype=complex_)

    def apply(self, v: np.ndarray, out: np.ndarray) -> np.ndarray:
        """out = (A^H A + lambda I) v (compact halves)."""
        grid = self._fft.to_space(v)
        grid *= self._circulant
        self._fft.from_space(grid, out)
        self._axpy(v.reshape(-1), out.reshape(-1), a=self.lam)
        return out


def solve(system: DampedNormalEquations, rhs: np.ndarray, band: np.ndarray, tolerance: float,
          max_iterations: int) -> Solution:
    """CG from 0 until |band * r| <= tolerance |band * rhs| or max_iterations.

    In-place BLAS updates on preallocated arrays: the arrays are small (N - 1, N/2), so allocations and
    temporaries would cost as much as the arithmetic.
    """
    x = np.zeros_like(rhs)
    r = rhs.copy()
    p = r.copy()
    q = np.empty_like(rhs)
    weighted = np.empty_like(rhs)
    axpy = get_blas_funcs("axpy", (x,))
    x_flat, r_flat, p_flat, q_flat = (a.reshape(-1) for a in (x, r, p, q))  # views: axpy updates in place

    def band_norm2() -> float:
        np.multiply(r, band, out=weighted)
        return dot(weighted, weighted)

    rr = dot(r, r)
    b_band2 = band_norm2()
    if b_band2 == 0:
        return Solution(x, 0, 0.0)
    tol2 = tolerance**2 * b_band2
    r_band2 = b_band2
    iterations = 0
    while iterations < max_iterations and r_band2 > tol2:
        system.apply(p, q)
        alpha = rr / dot(p, q)
        axpy(p_flat, x_flat, a=alpha)
        axpy(q_flat, r_flat, a=-alpha)
        rr, rr_old = dot(r, r), rr
        p *= rr / rr_old
        p += r
        r_band2 = band_norm2()
        iterations += 1
    return Solution(x, iterations, float(np.sqrt(r_band2 / b_band2)))
