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

Per step, all right-hand sides' vector updates, inner products and damping term are one compiled call
(cg_kernels.py): as numpy and BLAS calls they cost a third of each step in call overhead. The operator's buffers
are made once per grid and precision (DampedNormalEquations; each frame only sets its kernel), so a step allocates
nothing.

No preconditioner: the slow modes are band-limited ones straddling the patch border, which a preconditioner
diagonal in space (T. Chan's optimal circulant, density compensation) cannot separate; both cost iterations.
Smoothed and floored densities save iterations on spheres but not on faces for the same eps0 accuracy, weights
diagonal in frequency (following the band) slow CG down, and a coarse-grid solve as the starting point saves none.
Minimising the band-weighted residual itself (GMRES in that norm) passes the stopping test sooner but leaves eps0
further from the converged value than CG does at the same test.
"""

from __future__ import annotations

from dataclasses import dataclass

import ducc0
import numpy as np

from tofd.algorithm.features.compiled import compiled

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


def load_kernels(dtype: type[np.complexfloating]) -> None:
    """Load the compiled loops for halves of complex `dtype` now (compiling them the first time on a machine), not
    in the first solve: a live run's first frames would wait for it."""
    real = np.finfo(dtype).dtype
    v = np.zeros((1, 1, 2), real)
    weights, rows, norms = norm_weights(np.ones((1, 1))), np.zeros(1, np.intp), np.ones(1)
    hermitian_norms(np.zeros((1, 1), dtype), weights)
    compiled("cg_kernels").cg_step(v, v.copy(), v.copy(), v.copy(), 0.0, weights, rows, norms, norms.copy(),
                                   norms.copy())


def hermitian_norms(half: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """(|f|^2, |band f|^2) over the full Hermitian spectrum of a compact half (N - 1, N/2); weights from
    norm_weights(band)."""
    return compiled("cg_kernels").norms(_as_reals(half)[0], weights, np.arange(len(half)))


class DampedNormalEquations:
    """A^H A (product) and lambda (added in CG's step) on the 2N x 2N grid for N x N modes, for one frame's points at
    a time: made once with its buffers, given each frame's kernel by set_kernel (like a finufft plan its points).

    The FFTs are ducc0's, on one thread: it writes into given arrays, vectorises the transforms along a strided
    axis, and has no per-call dispatch of scipy.fft.
    """

    def __init__(self, n: int, real: type[np.floating], complex_: type[np.complexfloating]):
        self.lam, self.dtype = 0.0, complex_
        self._n, self._h, self._size = n, n // 2, 2 * n
        self.data_rows = np.r_[: self._h, self._size - self._h + 1: self._size]  # of the embedded layout
        self._half = np.empty((2 * n, n + 1), complex_)  # the kernel's, transformed into the circulant
        self._circulant = np.empty((2 * n, 2 * n), real)
        self._buffers: dict[int, tuple[np.ndarray, ...]] = {}

    def set_kernel(self, kernel: np.ndarray, lam: float) -> DampedNormalEquations:
        """Take this frame's K (2N, >= N + 1), the type-1 sums on the 2N x 2N grid in FFT order (finufft modeord=1;
        columns kx = 0 .. N used), and lambda; returns self."""
        n, half = self._n, self._half
        half[:] = kernel[:, : n + 1]
        half[n, :] = 0  # the unpaired -N row and column never enter (A^H A f)_k for |k| < N/2
        half[:, n] = 0
        # the inverse transform's 1 / (2N)^2 (inorm=2), which product's transforms leave out, is folded in here
        ducc0.fft.c2r(half, axes=(0, 1), lastsize=2 * n, forward=False, inorm=2, out=self._circulant, nthreads=1)
        self.lam = lam
        return self

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

    One batched operator product and one compiled update of all rhs per step. A converged rhs leaves the batch,
    so each answer is (to rounding) the one its own solve would give.
    """
    kernels = compiled("cg_kernels")
    data_rows, product, lam = system.data_rows, system.product, system.lam
    r = system.embed(rhs)
    x, p, q = np.zeros_like(r), r.copy(), np.empty_like(r)
    norms = np.array([kernels.norms(v, weights, data_rows) for v in _as_reals(r)[0]])  # (V, 2)
    rr, banded = norms[:, 0].copy(), norms[:, 1].copy()
    initial, limit = banded.copy(), tolerance**2 * banded
    rows, reals = np.arange(len(rhs)), _as_reals(x, r, p, q)
    solutions: dict[int, Solution] = {}
    above, iterations = int(np.count_nonzero(banded > limit)), 0
    while True:
        if above < len(rows) or iterations == max_iterations:
            done = ~(banded > limit) | (iterations == max_iterations)
            for j in np.flatnonzero(done):
                residual = np.sqrt(banded[j] / initial[j]) if initial[j] > 0 else 0.0
                solutions[int(rows[j])] = Solution(system.compact(x[j]), iterations, float(residual))
            if done.all():
                return [solutions[i] for i in range(len(rhs))]
            keep = ~done
            rows, x, r, p, q = rows[keep], x[keep], r[keep], p[keep], q[keep]
            rr, banded, initial, limit = rr[keep], banded[keep], initial[keep], limit[keep]
            reals = _as_reals(x, r, p, q)
        product(p, q)
        above = kernels.cg_step(*reals, lam, weights, data_rows, rr, banded, limit)
        iterations += 1
