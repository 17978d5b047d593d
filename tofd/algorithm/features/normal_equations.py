"""The NFFT path's damped normal equations (A^H A + lambda I) f = A^H z, solved by conjugate gradients.

Unknowns: the Fourier coefficients f_k of a real field on the N x N mode grid k in [-N/2, N/2)^2, stored as
the compact half spectrum (N - 1, N/2) complex: rows ky = 0 .. N/2 - 1, -N/2 + 1 .. -1 (FFT order without the
unpaired Nyquist row), columns kx = 0 .. N/2 - 1. The other half follows by Hermitian symmetry. Several
right-hand sides on the same points (range and amplitude) are solved together, (V, N - 1, N/2): one batched
FFT per step for all of them, each stopping on its own residual.

Operator. A^H A is Toeplitz, (A^H A f)_k = sum_l K_{k-l} f_l with K_m = sum_j exp(-2 pi i m.x_j), so it is
applied as a circulant convolution on the 2N x 2N grid: one real FFT pair of size 2N, pruned to the modes
that hold data (the inverse transform along ky runs only over the N/2 columns kx = 0 .. N/2 - 1 that are
nonzero, the forward one only over the N/2 columns that are kept), which saves a quarter of the work.

Stopping. CG stops when the residual weighted by A(rho) (the filters' band) falls below the tolerance
relative to the weighted right-hand side: smooth surfaces put most of A^H z at low frequencies that the
filters ignore, and the plain residual stopped a sphere with eps0 off by 15 %.

No preconditioner: the slow modes are band-limited ones straddling the patch border, which a preconditioner
diagonal in space (T. Chan's optimal circulant, density compensation) cannot separate; both cost iterations.
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
    """Real FFTs of size 2N x 2N between compact half spectra (V, N - 1, N/2) and (V, 2N, 2N) real fields."""

    def __init__(self, n: int, dtype: type[np.complexfloating]):
        self.h, self.size, self.dtype = n // 2, 2 * n, dtype
        self._columns: dict[int, np.ndarray] = {}  # per V: the half spectra's columns, zero-padded in ky

    def to_space(self, half: np.ndarray) -> np.ndarray:
        """(V, 2N, 2N) real fields whose spectra are `half`, zero elsewhere (unnormalised inverse transform)."""
        h, v = self.h, len(half)
        if v not in self._columns:
            self._columns[v] = np.zeros((v, self.size, h), self.dtype)
        cols = self._columns[v]
        cols[:, :h] = half[:, :h]
        cols[:, self.size - h + 1:] = half[:, h:]
        return sfft.irfft(sfft.ifft(cols, axis=1, workers=1), n=self.size, axis=2, workers=1)

    def from_space(self, field: np.ndarray, out: np.ndarray) -> np.ndarray:
        """out = the compact halves of the fields' spectra (forward transform)."""
        h = self.h
        spec = sfft.fft(sfft.rfft(field, axis=2, workers=1)[:, :, :h], axis=1, workers=1)
        out[:, :h] = spec[:, :h]
        out[:, h:] = spec[:, self.size - h + 1:]
        return out


class HermitianInner:
    """Re <a, b> of full Hermitian spectra from compact halves (V, N - 1, N/2): kx > 0 counts twice."""

    def __init__(self, band: np.ndarray):
        weight = np.full(band.shape, 2.0, band.dtype)
        weight[:, 0] = 1.0
        self._plain = np.repeat(weight, 2, axis=1).reshape(-1)  # over the interleaved real and imaginary parts
        self._band = np.repeat(weight * band * band, 2, axis=1).reshape(-1)
        self._products: dict[int, np.ndarray] = {}

    def _products_of(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        real = a.real.dtype
        products = self._products.setdefault(len(a), np.empty((len(a), self._plain.size), real))
        return np.multiply(a.view(real).reshape(len(a), -1), b.view(real).reshape(len(b), -1), out=products)

    def dots(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(V,) Re <a_v, b_v>."""
        return self._products_of(a, b) @ self._plain

    def band_norms2(self, r: np.ndarray) -> np.ndarray:
        """(V,) |A(rho) r_v|^2: the residuals weighted by the filters' band."""
        return self._products_of(r, r) @ self._band


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
        """out = (A^H A + lambda I) v for each of the V compact halves."""
        grid = self._fft.to_space(v)
        grid *= self._circulant
        self._fft.from_space(grid, out)
        self._axpy(v.reshape(-1), out.reshape(-1), a=self.lam)
        return out


def solve(system: DampedNormalEquations, rhs: np.ndarray, band: np.ndarray, tolerance: float,
          max_iterations: int) -> list[Solution]:
    """CG from 0 on each rhs (V, N - 1, N/2) until |band * r| <= tolerance |band * rhs| or max_iterations.

    In place on preallocated arrays: they are small, so temporaries would cost as much as the arithmetic. A
    converged rhs leaves the batch, so each answer is (to rounding) the one its own solve would give.
    """
    inner = HermitianInner(band)
    axpy = get_blas_funcs("axpy", (rhs,))
    b_band2 = inner.band_norms2(rhs)
    solutions: dict[int, Solution] = {int(i): Solution(np.zeros_like(rhs[i]), 0, 0.0)
                                      for i in np.flatnonzero(b_band2 == 0)}
    active = np.flatnonzero(b_band2 > 0)
    if not active.size:
        return [solutions[i] for i in range(len(rhs))]
    x, r = np.zeros_like(rhs[active]), rhs[active].copy()
    p, q = r.copy(), np.empty_like(r)
    tol2, b_band2 = tolerance**2 * b_band2[active], b_band2[active]
    rr, r_band2 = inner.dots(r, r), b_band2.copy()
    iterations = 0
    while True:
        done = (r_band2 <= tol2) | (iterations >= max_iterations)
        for j in np.flatnonzero(done):
            solutions[int(active[j])] = Solution(x[j], iterations, float(np.sqrt(r_band2[j] / b_band2[j])))
        if done.all():
            return [solutions[i] for i in range(len(rhs))]
        if done.any():
            keep = ~done
            active, x, r, p, q = active[keep], x[keep], r[keep], p[keep], q[keep]
            tol2, b_band2, rr, r_band2 = tol2[keep], b_band2[keep], rr[keep], r_band2[keep]
        system.apply(p, q)
        alpha = rr / inner.dots(p, q)
        for row, a in enumerate(alpha.tolist()):
            axpy(p[row].reshape(-1), x[row].reshape(-1), a=a)
            axpy(q[row].reshape(-1), r[row].reshape(-1), a=-a)
        rr, rr_old = inner.dots(r, r), rr
        p *= (rr / rr_old)[:, None, None]
        p += r
        r_band2 = inner.band_norms2(r)
        iterations += 1
