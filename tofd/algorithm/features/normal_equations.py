"""The NFFT path's damped normal equations (A^H A + lambda I) f = A^H z, solved by conjugate gradients.

Unknowns: the Fourier coefficients f_k of a real field on the N x N mode grid k in [-N/2, N/2)^2. Callers see
the compact half spectrum (N - 1, N/2) complex: rows ky = 0 .. N/2 - 1, -N/2 + 1 .. -1 (FFT order without the
unpaired Nyquist row), columns kx = 0 .. N/2 - 1; the other half follows by Hermitian symmetry. The solver
keeps it embedded in the 2N x 2N grid's first N/2 columns, (2N, N/2) with zero rows ky = N/2 .. 3N/2 (embed,
compact), so the FFTs read and write the CG vectors in place. Several right-hand sides on the same points (range
and amplitude) are solved together, (V, ...): one batched FFT per step for all of them, each stopping on its own
residual.

Operator. A^H A is Toeplitz, (A^H A f)_k = sum_l K_{k-l} f_l with K_m = sum_j exp(-2 pi i m.x_j), so it is
applied as a circulant convolution on the 2N x 2N grid: one real FFT pair of size 2N, pruned to the modes
that hold data (the transforms along ky run only over the N/2 columns kx = 0 .. N/2 - 1 that hold data),
which saves a quarter of the work.

Stopping. CG stops when the residual weighted by A(rho) (the filters' band) falls below the tolerance
relative to the weighted right-hand side: smooth surfaces put most of A^H z at low frequencies that the
filters ignore, and the plain residual stopped a sphere with eps0 off by 15 %.

CG's vector updates, inner products and the damping term are one compiled loop per step (cg_kernels.py):
as numpy and BLAS calls they cost a third of each step in call overhead.

No preconditioner: the slow modes are band-limited ones straddling the patch border, which a preconditioner
diagonal in space (T. Chan's optimal circulant, density compensation) cannot separate; both cost iterations.
Smoothed and floored densities save iterations on spheres but not on faces for the same eps0 accuracy, weights
diagonal in frequency (following the band) slow CG down, and a coarse-grid solve as the starting point saves none.
Minimising the band-weighted residual itself (GMRES in that norm) passes the stopping test sooner but leaves eps0
further from the converged value than CG does at the same test.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from types import ModuleType

import ducc0
import numpy as np

_KY, _KX = (1,), (2,)  # the axes of (V, 2N, ...) fields and spectra: ky (rows) and kx (columns)


@dataclass(frozen=True, slots=True)
class Solution:
    """f: (N - 1, N/2) compact half spectrum; iterations; residual: final relative band-weighted residual."""

    f: np.ndarray
    iterations: int
    residual: float


def norm_weights(band: np.ndarray) -> np.ndarray:
    """(2, N - 1, N) weights on the real and imaginary parts of compact halves (N - 1, N/2) viewed as reals: row 0
    gives |v|^2 and row 1 |band v|^2 over the full Hermitian spectrum (kx > 0 counts twice)."""
    twice = np.full(band.shape, 2.0)
    twice[:, 0] = 1.0
    return np.repeat(np.stack((twice, twice * band.astype(np.float64) ** 2)), 2, axis=-1)


@functools.cache
def _kernels() -> ModuleType:
    """The compiled loops (cg_kernels.py), imported on first use: only processes that solve load numba."""
    from tofd.algorithm.features import cg_kernels

    return cg_kernels


def load_kernels(dtype: type[np.complexfloating]) -> None:
    """Load the compiled loops for halves of complex `dtype` now (compiling them the first time on a machine), not
    in the first solve: a live run's first frames would wait for it."""
    real = np.finfo(dtype).dtype
    v = np.zeros((1, 2), real)
    weights, rows = norm_weights(np.ones((1, 1))), np.zeros(1, np.intp)
    hermitian_norms(np.zeros((1, 1), dtype), weights)
    _kernels().cg_step(v, v.copy(), v.copy(), v.copy(), 0.0, weights, rows, 1.0)


def hermitian_norms(half: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """(|f|^2, |band f|^2) over the full Hermitian spectrum of a compact half (N - 1, N/2); weights from
    norm_weights(band)."""
    return _kernels().norms(_as_reals(half)[0], weights, np.arange(len(half)))


class DampedNormalEquations:
    """A^H A (product) and lambda (added in CG's step) for one frame's points, from K on the 2N x 2N grid (finufft
    type 1, modeord=1).

    The FFTs are ducc0's, on one thread: it writes into given arrays, vectorises the transforms along a strided
    axis, and has no per-call dispatch of scipy.fft.
    """

    def __init__(self, kernel: np.ndarray, lam: float, n: int, real: type[np.floating],
                 complex_: type[np.complexfloating]):
        self.lam, self.dtype = lam, complex_
        self._h, self._size = n // 2, 2 * n
        self.data_rows = np.r_[: self._h, self._size - self._h + 1: self._size]  # of the embedded layout
        half = kernel[:, : n + 1].astype(complex_)  # a copy
        half[n, :] = 0  # the unpaired -N row and column never enter (A^H A f)_k for |k| < N/2
        half[:, n] = 0
        # the inverse transform's 1 / (2N)^2 (inorm=2), which product's transforms leave out, is folded in here
        self._circulant = ducc0.fft.c2r(half, axes=(0, 1), lastsize=2 * n, forward=False, inorm=2,
                                        out=np.empty((2 * n, 2 * n), real), nthreads=1)
        self._buffers: dict[int, tuple[np.ndarray, ...]] = {}

    def embed(self, half: np.ndarray) -> np.ndarray:
        """(V, 2N, N/2) embedded copies of compact halves (V, N - 1, N/2)."""
        h = self._h
        out = np.zeros((len(half), self._size, h), self.dtype)
        out[:, :h] = half[:, :h]
        out[:, self._size - h + 1:] = half[:, h:]
        return out

    def compact(self, embedded: np.ndarray) -> np.ndarray:
        """(..., N - 1, N/2) compact halves of embedded (..., 2N, N/2) ones."""
        h = self._h
        return np.concatenate((embedded[..., :h, :], embedded[..., self._size - h + 1:, :]), axis=-2)

    def _buffers_for(self, v: int) -> tuple[np.ndarray, ...]:
        """For V fields: the inverse's (V, 2N, N + 1) spectra (zero beyond kx = N/2 - 1) and its columns with data,
        the (V, 2N, 2N) fields, the forward's spectra and its columns kept."""
        if v not in self._buffers:
            size, real, h = self._size, np.finfo(self.dtype).dtype, self._h
            spectra = (v, size, size // 2 + 1)
            inverse, forward = np.zeros(spectra, self.dtype), np.empty(spectra, self.dtype)
            self._buffers[v] = (inverse, inverse[:, :, :h], np.empty((v, size, size), real), forward,
                                forward[:, :, :h])
        return self._buffers[v]

    def product(self, v: np.ndarray, out: np.ndarray) -> np.ndarray:
        """out = A^H A v for embedded halves v (V, 2N, N/2) (out's rows without data: left over, not zero).

        ducc0's arguments are positional (a, axes, [lastsize,] forward, inorm, out, nthreads = 1: the compute
        processes' one-thread rule): parsing keywords is a measurable part of transforms this small."""
        spectra, data_columns, fields, forward, kept_columns = self._buffers_for(len(v))
        ducc0.fft.c2c(v, _KY, False, 0, data_columns, 1)  # inverse along ky, only the columns with data
        ducc0.fft.c2r(spectra, _KX, self._size, False, 0, fields, 1)  # inverse along kx
        np.multiply(fields, self._circulant, out=fields)
        ducc0.fft.r2c(fields, _KX, True, 0, forward, 1)  # forward along x
        return ducc0.fft.c2c(kept_columns, _KY, True, 0, out, 1)  # forward along y, only the columns kept


def _as_reals(*arrays: np.ndarray) -> list[np.ndarray]:
    """Views of complex arrays as reals, the last axis doubled (real and imaginary parts interleaved)."""
    return [a.view(np.finfo(a.dtype).dtype) for a in arrays]


def solve(system: DampedNormalEquations, rhs: np.ndarray, weights: np.ndarray, tolerance: float,
          max_iterations: int) -> list[Solution]:
    """CG from 0 on each rhs (V, N - 1, N/2) until |band * r| <= tolerance |band * rhs| or max_iterations
    (weights: norm_weights(band)).

    One batched operator product per step, then one compiled update per rhs. A converged rhs leaves the batch,
    so each answer is (to rounding) the one its own solve would give.
    """
    data_rows, step, product, lam = system.data_rows, _kernels().cg_step, system.product, system.lam
    rows = list(range(len(rhs)))
    norms = [hermitian_norms(b, weights) for b in rhs]
    r = system.embed(rhs)
    x, p, q = np.zeros_like(r), r.copy(), np.empty_like(r)
    per_row = list(zip(*_as_reals(x, r, p, q), strict=True))  # each rhs's (x, r, p, q) viewed as reals
    rr, r_band2 = [n[0] for n in norms], [n[1] for n in norms]
    b_band2 = list(r_band2)
    limit = [tolerance**2 * b for b in b_band2]
    solutions: dict[int, Solution] = {}
    iterations = 0
    while True:
        keep = [j for j in range(len(rows)) if r_band2[j] > limit[j] and iterations < max_iterations]
        if len(keep) < len(rows):
            for j in sorted(set(range(len(rows))) - set(keep)):
                residual = np.sqrt(r_band2[j] / b_band2[j]) if b_band2[j] > 0 else 0.0
                solutions[rows[j]] = Solution(system.compact(x[j]), iterations, float(residual))
            if not keep:
                return [solutions[i] for i in range(len(rhs))]
            rows, x, r, p, q = [rows[j] for j in keep], x[keep], r[keep], p[keep], q[keep]
            per_row = list(zip(*_as_reals(x, r, p, q), strict=True))
            b_band2, r_band2, rr, limit = ([v[j] for j in keep] for v in (b_band2, r_band2, rr, limit))
        product(p, q)
        for j, (xj, rj, pj, qj) in enumerate(per_row):
            rr[j], r_band2[j] = step(xj, rj, pj, qj, lam, weights, data_rows, rr[j])
        iterations += 1
