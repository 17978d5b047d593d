"""The band of the feature filters: the radial tuning A(rho) and the highest frequency where it still matters.

A(rho) = T(rho) G(rho): the radial tuning T(rho) = (rho/rho0)^2 exp(1 - rho^2 / rho0^2) (peak 1 at rho0) times a
Gaussian low-pass G(rho) = exp(-rho^2 / (2 sigma^2)), all frequencies in cycles per metre. Its product is
(u / rho0^2) e exp(-u / u_e) in u = rho^2, with 1 / u_e = 1 / rho0^2 + 1 / (2 sigma^2): it peaks at u = u_e and
falls to `BAND_FLOOR` of its peak at u = s u_e, s the root > 1 of s exp(1 - s) = BAND_FLOOR.

The band edge decides what a grid or a camera must carry: the NFFT grid must reach it (FeatureConfig), and the
pixels at the object's range must sample the band without aliasing one grid mode onto another (features.nfft).
Numpy only, so the config can check it without loading the transforms.
"""

from __future__ import annotations

import math

import numpy as np

BAND_FLOOR = 0.02  # A(rho) below this fraction of its peak is outside the band


def radial_tuning(rho_per_m: np.ndarray | float, rho0_per_m: float, sigma_per_m: float) -> np.ndarray:
    """A(rho) = (rho/rho0)^2 exp(1 - (rho/rho0)^2) exp(-rho^2 / (2 sigma^2)); all frequencies in cycles per metre."""
    r2 = (np.asarray(rho_per_m, dtype=np.float64) / rho0_per_m) ** 2
    lowpass = np.exp(-0.5 * (np.asarray(rho_per_m) / sigma_per_m) ** 2)
    return r2 * np.exp(1.0 - r2) * lowpass


def band_edge_per_m(rho0_per_m: float, sigma_per_m: float, floor: float = BAND_FLOOR) -> float:
    """The frequency (cycles per metre) above A's peak where A(rho) falls to `floor` (0 < floor < 1) of its peak."""
    if not 0.0 < floor < 1.0:
        raise ValueError(f"floor: {floor} is not in (0, 1)")
    u_e = 1.0 / (1.0 / rho0_per_m**2 + 0.5 / sigma_per_m**2)
    s = 1.0 - 2.0 * math.log(floor)  # Newton on ln s + 1 - s = ln floor from the right of the root
    for _ in range(50):
        step = (math.log(s) + 1.0 - s - math.log(floor)) / (1.0 / s - 1.0)
        s -= step
        if abs(step) < 1e-12 * s:
            break
    return math.sqrt(s * u_e)
