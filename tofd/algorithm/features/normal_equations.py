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
Smoothed and floored densities save iterations on spheres but not on faces for the same eps0 accuracy, and
weights diagonal in frequency (following the band) slow CG down.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from scipy.fft._pocketfft import pypocketfft as pocketfft
from scipy.linalg.blas import get_blas_funcs


@dataclass(frozen=True, slots=True)
class Solution:
    """f: (N - 1, N/2) compact half spectrum; iterations; residual: final relative band-weighted residual."""

    f: np.ndarray
    iterations: int
    residual: float


class PrunedRealFFT:
    """Unnormalised real FFTs of size 2N x 2N between compact half spectra (V, N - 1, N/2) and (V, 2N, 2N)
    real fields, into buffers kept per V.

    They call scipy's pocketfft binding (the engine behind scipy.fft) directly: it writes into given arrays and
    skips scipy.fft's per-call dispatch, which at 2N = 144 costs a quarter of each CG step.
    """

    def __init__(self, n: int, dtype: type[np.complexfloating]):
        self.h, self.size, self.dtype = n // 2, 2 * n, dtype
        self._buffers: dict[int, tuple[np.ndarray, ...]] = {}

    def _buffers_for(self, v: int) -> tuple[np.ndarray, ...]:
        """For V fields: the inverse's (V, 2N, N + 1) spectra (zero beyond kx = N/2 - 1), the (V, 2N, 2N) fields,
        the forward's spectra and its (V, 2N, N/2) columns."""
        if v not in self._buffers:
            size, real = self.size, np.finfo(self.dtype).dtype
            spectra = (v, size, size // 2 + 1)
            self._buffers[v] = (np.zeros(spectra, self.dtype), np.empty((v, size, size), real),
                                np.empty(spectra, self.dtype), np.empty((v, size, self.h), self.dtype))
        return self._buffers[v]

    def to_space(self, half: np.ndarray) -> np.ndarray:
        """(V, 2N, 2N) real fields whose spectra are `half`, zero elsewhere (a buffer, overwritten next call)."""
        h, size = self.h, self.size
        spectra, fields, _, _ = self._buffers_for(len(half))
        columns = spectra[:, :, :h]
        columns[:, :h] = half[:, :h]
        columns[:, h:size - h + 1] = 0
        columns[:, size - h + 1:] = half[:, h:]
        pocketfft.c2c(columns, (1,), False, 0, columns, 1)  # along ky, only the columns that hold data
        return pocketfft.c2r(spectra, (2,), size, False, 0, fields, 1)

    def from_space(self, fields: np.ndarray, out: np.ndarray) -> np.ndarray:
        """out = the compact halves of the fields' spectra."""
        h, size = self.h, self.size
        _, _, spectra, columns = self._buffers_for(len(fields))
        pocketfft.r2c(fields, (2,), True, 0, spectra, 1)
        pocketfft.c2c(spectra[:, :, :h], (1,), True, 0, columns, 1)  # along ky, only the columns kept
        out[:, :h] = columns[:, :h]
        out[:, h:] = columns[:, size - h + 1:]
        return out


class HermitianInner:
    """Re <a, b> of full Hermitian spectra from compact halves (N - 1, N/2): kx > 0 counts twice."""

    def __init__(self, band: np.ndarray, dtype: np.dtype):
        root = np.full(band.shape, np.sqrt(2.0), band.dtype)
        root[:, 0] = 1.0
        self._band_root = root * band  # |band_root * r|^2 = sum over the full spectrum of A(rho)^2 |r|^2
        self._scratch = np.empty(band.shape, dtype)

    def dot(self, a: np.ndarray, b: np.ndarray) -> float:
        """Re <a, b>: BLAS dot products, no temporaries (the kx = 0 column counted once)."""
        return 2.0 * float(np.vdot(a, b).real) - float(np.vdot(a[:, 0], b[:, 0]).real)

    def band_norm2(self, r: np.ndarray) -> float:
        """|A(rho) r|^2: the residual weighted by the filters' band."""
        weighted = np.multiply(r, self._band_root, out=self._scratch)
        return float(np.vdot(weighted, weighted).real)


class DampedNormalEquations:
    """A^H A + lambda I for one frame's points, from K on the 2N x 2N grid (finufft type 1, modeord=1)."""

    def __init__(self, kernel: np.ndarray, lam: float, n: int, real: type[np.floating],
                 complex_: type[np.complexfloating]):
        self.lam = lam
        self._fft = PrunedRealFFT(n, complex_)
        half = kernel[:, : n + 1].copy()
        half[n, :] = 0  # the unpaired -N row and column never enter (A^H A f)_k for |k| < N/2
        half[:, n] = 0
        # the inverse transform's 1 / (2N)^2, which PrunedRealFFT leaves out, is folded in here
        self._circulant = sfft.irfft2(half, s=(2 * n, 2 * n), workers=1).astype(real, copy=False)
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

    One batched operator product per step; the rest in place, per rhs, with BLAS calls and Python floats: the
    vectors are small, so temporaries and broadcasting would cost as much as the arithmetic. A converged rhs
    leaves the batch, so each answer is (to rounding) the one its own solve would give.
    """
    inner = HermitianInner(band, rhs.dtype)
    axpy = get_blas_funcs("axpy", (rhs,))
    rows = list(range(len(rhs)))
    x, r = np.zeros_like(rhs), rhs.copy()
    p, q = r.copy(), np.empty_like(r)
    b_band2 = [inner.band_norm2(b) for b in rhs]
    r_band2, rr = list(b_band2), [inner.dot(v, v) for v in r]
    solutions: dict[int, Solution] = {}
    iterations = 0
    while True:
        keep = [j for j in range(len(rows))
                if r_band2[j] > tolerance**2 * b_band2[j] and iterations < max_iterations]
        if len(keep) < len(rows):
            for j in sorted(set(range(len(rows))) - set(keep)):
                residual = np.sqrt(r_band2[j] / b_band2[j]) if b_band2[j] > 0 else 0.0
                solutions[rows[j]] = Solution(x[j], iterations, float(residual))
            if not keep:
                return [solutions[i] for i in range(len(rhs))]
            rows, x, r, p, q = [rows[j] for j in keep], x[keep], r[keep], p[keep], q[keep]
            b_band2, r_band2, rr = ([v[j] for j in keep] for v in (b_band2, r_band2, rr))
        system.apply(p, q)
        for j in range(len(rows)):
            alpha = rr[j] / inner.dot(p[j], q[j])
            axpy(p[j].reshape(-1), x[j].reshape(-1), a=alpha)
            axpy(q[j].reshape(-1), r[j].reshape(-1), a=-alpha)
            rr_old, rr[j] = rr[j], inner.dot(r[j], r[j])
            p[j] *= rr[j] / rr_old
            p[j] += r[j]
            r_band2[j] = inner.band_norm2(r[j])
        iterations += 1
