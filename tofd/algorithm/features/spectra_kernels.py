"""The NFFT path's compiled loops between finufft's grids and the solver's half spectra (numba, compiled once and
cached on disk; imported on first use, compiled.py): one pass each instead of a handful of numpy passes and
temporaries (tofd.algorithm.features.nfft)."""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def pack_pairs(rows: np.ndarray, scales: np.ndarray, out: np.ndarray) -> None:
    """out[p] = rows[2p] / scales[2p] + i rows[2p + 1] / scales[2p + 1] (imaginary part 0 past the last row): R real
    sets (R, M) as (ceil(R / 2), M) complex strengths."""
    for p in range(out.shape[0]):
        v = 2 * p
        for j in range(rows.shape[1]):
            imag = rows[v + 1, j] / scales[v + 1] if v + 1 < rows.shape[0] else 0.0
            out[p, j] = complex(rows[v, j] / scales[v], imag)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def separate_pairs(grids: np.ndarray, scales: np.ndarray, out: np.ndarray) -> None:
    """out[2p] = scales[2p] (G_p + G*_p(-m)) and out[2p + 1] = -i scales[2p + 1] (G_p - G*_p(-m)) on the first
    out.shape[2] columns; G: grids (P, S, S) in FFT order, G_p(-m) its mode -m (mod S); out (R <= 2P, S, columns)."""
    size = grids.shape[1]
    for v in range(out.shape[0]):
        p, f, odd = v // 2, scales[v], v % 2
        for i in range(size):
            row, mirror_row = grids[p, i], grids[p, (size - i) % size]
            for j in range(out.shape[2]):
                g, mirrored = row[j], mirror_row[size - j if j else 0]
                if odd:  # (G - G*(-m)) times -i f
                    out[v, i, j] = complex(f * (g.imag + mirrored.imag), -f * (g.real - mirrored.real))
                else:
                    out[v, i, j] = complex(f * (g.real + mirrored.real), f * (g.imag - mirrored.imag))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def hermitian_full(half: np.ndarray, out: np.ndarray) -> None:
    """out (N, N): the FFT-ordered spectrum of a real field from its compact half (N - 1, N/2) (rows ky = 0 .. N/2 - 1,
    -N/2 + 1 .. -1; columns kx = 0 .. N/2 - 1), the rest by Hermitian symmetry F(-k) = conj F(k), the Nyquist row and
    column 0."""
    n = out.shape[0]
    h = n // 2
    for i in range(n):
        mirror = (n - i) % n
        for j in range(n):
            if i == h or j == h:
                out[i, j] = 0
            elif j < h:
                out[i, j] = half[i if i < h else i - 1, j]
            else:
                out[i, j] = np.conj(half[mirror if mirror < h else mirror - 1, n - j])
