"""The NFFT solver's compiled loops (numba, compiled once and cached on disk): CG's step and its norms on half
spectra viewed as reals, (rows, N) with the real and imaginary parts interleaved (normal_equations.py); imported on
first use (compiled.py).
"""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def norms(v: np.ndarray, weights: np.ndarray, rows: np.ndarray) -> tuple[float, float]:
    """(|v|^2, |band v|^2) of a half spectrum viewed as reals (rows, N) whose rows `rows` hold the data."""
    plain = banded = 0.0
    for i in range(rows.size):
        row = rows[i]
        for j in range(v.shape[1]):
            a = v[row, j] * v[row, j]
            plain += weights[0, i, j] * a
            banded += weights[1, i, j] * a
    return plain, banded


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _step(x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, lam: float, weights: np.ndarray,
          rows: np.ndarray, rr: float) -> tuple[float, float]:
    """cg_step for one half (2N, N): returns its new (|r|^2, |band r|^2)."""
    pq = 0.0
    for i in range(rows.size):
        row = rows[i]
        for j in range(p.shape[1]):
            q[row, j] += lam * p[row, j]
            pq += weights[0, i, j] * p[row, j] * q[row, j]
    alpha = rr / pq
    for i in range(rows.size):
        row = rows[i]
        for j in range(p.shape[1]):
            x[row, j] += alpha * p[row, j]
            r[row, j] -= alpha * q[row, j]
    rr_new, banded = norms(r, weights, rows)
    beta = rr_new / rr
    for i in range(rows.size):
        row = rows[i]
        for j in range(p.shape[1]):
            p[row, j] = r[row, j] + beta * p[row, j]
    return rr_new, banded


@numba.njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def cg_step(x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, lam: float, weights: np.ndarray,
            rows: np.ndarray, rr: np.ndarray, banded: np.ndarray, limit: np.ndarray) -> int:
    """One CG step on V embedded halves viewed as reals (V, 2N, N), q = A^H A p on entry, rows: those holding data.

    Per half: adds lam p to q, updates x, r, p in place, and rr (|r|^2, float64 (V,)) and banded (|band r|^2) to
    the new residual's. Returns how many halves' banded is still above their limit (V,).
    """
    above = 0
    for v in range(x.shape[0]):
        rr[v], banded[v] = _step(x[v], r[v], p[v], q[v], lam, weights, rows, rr[v])
        above += banded[v] > limit[v]
    return above
