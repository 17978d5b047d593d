"""Linear surface operators given by their transfer functions, evaluated on a feature path's frequency grid.

A transfer function is a callable `transfer(kx, ky)` taking spatial frequencies in cycles per metre (numpy arrays
that broadcast; x right, y down) and returning the operator's complex transfer values of their broadcast shape, or
a stack of K operators (K, *shape). Filtering a real surface z gives the field IFT(H . FT(z)); it is real where
the operator is Hermitian, H(-k) = conj(H(k)) (every even real filter, and i^n A(rho) cos(n theta) for any n),
complex otherwise. The default operators are the eccentricity filters [C0, C2, S2] of transfer.py.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tofd.algorithm.features.transfer import transfer_functions
from tofd.algorithm.params import FeatureConfig

Transfer = Callable[[np.ndarray, np.ndarray], np.ndarray]
MAX_OPERATORS = 64
"""Most operators one transfer may return (each costs a field of the image's size per frame)."""


def eccentricity_transfer(cfg: FeatureConfig) -> Transfer:
    """The transfer of [C0, C2, S2] for the band of `cfg` (eps0 = c0^2, eps2 = c2^2 + s2^2)."""
    rho0, sigma = cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m
    return lambda kx, ky: transfer_functions(kx, ky, rho0, sigma)


@dataclass(frozen=True, slots=True)
class OperatorGrid:
    """K operators on a frequency grid: values (K, *grid), float64 where all are real, else complex128; hermitian:
    every operator satisfies H(-k) = conj(H(k)), so it maps real surfaces to real fields; stacked: the transfer
    returned a stack (K, *grid) rather than one operator (*grid)."""

    values: np.ndarray
    hermitian: bool
    stacked: bool

    def __len__(self) -> int:
        return len(self.values)


def evaluate(transfer: Transfer, kx_per_m: np.ndarray, ky_per_m: np.ndarray) -> OperatorGrid:
    """`transfer` on the grid (kx, ky) (broadcasting, cycles per metre); ValueError naming `transfer` unless it
    returns finite values of the grid's shape, or a stack of them."""
    kx, ky = np.broadcast_arrays(np.asarray(kx_per_m, dtype=np.float64), np.asarray(ky_per_m, dtype=np.float64))
    (values, stacked), (mirrored, _) = _call(transfer, kx, ky), _call(transfer, -kx, -ky)
    scale = float(np.max(np.abs(values), initial=0.0))
    hermitian = bool(np.allclose(mirrored, np.conj(values), rtol=1e-9, atol=1e-12 * scale))
    if not np.iscomplexobj(values) or not np.any(values.imag):
        values = np.ascontiguousarray(values.real, dtype=np.float64)
    return OperatorGrid(values, hermitian, stacked)


def _call(transfer: Transfer, kx: np.ndarray, ky: np.ndarray) -> tuple[np.ndarray, bool]:
    """(K, *shape) values of `transfer` at (kx, ky) of one shape, and whether it returned a stack."""
    try:
        values = np.asarray(transfer(kx, ky))
    except Exception as exc:  # the user's callable: name it in one clear error
        raise ValueError(f"transfer raised {type(exc).__name__} on frequency arrays of shape {kx.shape}: "
                         f"{exc}") from exc
    stacked = values.shape != kx.shape
    if not stacked:
        values = values[None]
    if values.ndim != kx.ndim + 1 or values.shape[1:] != kx.shape or len(values) == 0:
        raise ValueError(f"transfer must return an array of shape {kx.shape} or (K, *{kx.shape}) for frequency arrays "
                         f"of shape {kx.shape}, got {values.shape}")
    if len(values) > MAX_OPERATORS:  # before any copy: a broadcast stack costs nothing until it is copied
        raise ValueError(f"transfer returned {len(values)} operators, at most {MAX_OPERATORS} are applied at once")
    if not np.issubdtype(values.dtype, np.number) or np.issubdtype(values.dtype, np.bool_):
        raise ValueError(f"transfer must return numbers, got dtype {values.dtype}")
    values = values.astype(np.complex128 if np.iscomplexobj(values) else np.float64, copy=False)
    if not np.all(np.isfinite(values)):
        raise ValueError("transfer returned non-finite values (NaN or inf)")
    return values, stacked
