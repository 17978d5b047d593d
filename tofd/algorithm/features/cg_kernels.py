"""The NFFT solver's compiled loops (numba, compiled once and cached on disk): CG's step and its norms on half
spectra viewed as reals, (rows, N) with the real and imaginary parts interleaved (normal_equations.py).

numba and LLVM add about 40 MB of private memory (100 MB resident) to a process, so normal_equations imports
this module only when it first solves: the feature workers load it, the service and viewer processes do not.
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
def cg_step(x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, lam: float, weights: np.ndarray,
            rows: np.ndarray, rr: float) -> tuple[float, float]:
    """One CG step on embedded halves viewed as reals (2N, N), q = A^H A p on entry, rows: those holding data.

    Adds lam p to q, updates x, r, p in place; returns (|r|^2, |band r|^2) of the new residual.
    """
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
