"""Transfer functions of the generalized eccentricities, in physical frequencies (cycles per metre at e).

C_n(k) = i^n A(rho) cos(n theta),  S_n(k) = i^n A(rho) sin(n theta),  n = 0, 2,
with rho = |k| in cycles per metre and theta the angle of k (x right, y down). For n = 0 and 2 the factor
i^n is real (+1, -1), so all three non-trivial filters are real and even in k: C0 = A, C2 = -A cos 2theta,
S2 = -A sin 2theta (S0 = 0). Filtering a real surface with them gives real fields c0, c2, s2 and
eps0 = c0^2, eps2 = c2^2 + s2^2 (metres^2 on range, squared input units otherwise).

A(rho) is the radial tuning of tofd.algorithm.band (a tuning peak at rho0 times a Gaussian low-pass that keeps the
filter inside the band of the NFFT grid). It goes as rho^2 near 0 (a Laplacian of Gaussian in space), so the filter
is local: any plane gives exactly 0 and a sphere's apex response depends only on its curvature, which is what makes
the NFFT features scale-invariant.

Both feature paths call `transfer_functions` with physical frequencies, so they apply the same filter:
- FFT path: pixel frequency (cycles/pixel) times f/e (a pixel spans e/f metres at the equivalence range);
- NFFT path: mode index k divided by the side of the patch in metres (FeatureConfig.patch_width_m, patch_height_m).
"""

from __future__ import annotations

import numpy as np

from tofd.algorithm.band import radial_tuning
from tofd.drivers.intrinsics import Intrinsics


def transfer_functions(kx_per_m: np.ndarray, ky_per_m: np.ndarray, rho0_per_m: float,
                       sigma_per_m: float) -> np.ndarray:
    """(3, ...) real filters [C0, C2, S2] at physical frequencies (kx, ky) in cycles per metre (broadcast), for
    the radial tuning A(rho) of `radial_tuning`."""
    kx, ky = np.broadcast_arrays(np.asarray(kx_per_m, dtype=np.float64), np.asarray(ky_per_m, dtype=np.float64))
    a = radial_tuning(np.hypot(kx, ky), rho0_per_m, sigma_per_m)
    theta2 = 2 * np.arctan2(ky, kx)
    return np.stack([a, -a * np.cos(theta2), -a * np.sin(theta2)])


def eccentricity_filters(kx_per_m: np.ndarray, ky_per_m: np.ndarray, n: int, rho0_per_m: float,
                         sigma_per_m: float) -> np.ndarray:
    """(2, ...) complex filters [C_n, S_n] = i^n A(rho) [cos(n theta), sin(n theta)] at physical frequencies (kx, ky)
    in cycles per metre (broadcast); eps_n = c_n^2 + s_n^2 of the fields they give (S_0 = 0)."""
    kx, ky = np.broadcast_arrays(np.asarray(kx_per_m, dtype=np.float64), np.asarray(ky_per_m, dtype=np.float64))
    a = (1j ** n) * radial_tuning(np.hypot(kx, ky), rho0_per_m, sigma_per_m)
    theta = np.arctan2(ky, kx)
    return np.stack([a * np.cos(n * theta), a * np.sin(n * theta)])


def pixel_frequencies_per_m(pixel_freq_x: np.ndarray, pixel_freq_y: np.ndarray, intrinsics: Intrinsics,
                            equivalence_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """FFT path: cycles/pixel -> cycles/metre at the equivalence range (times f/e per axis)."""
    return (np.asarray(pixel_freq_x) * intrinsics.fx / equivalence_range_m,
            np.asarray(pixel_freq_y) * intrinsics.fy / equivalence_range_m)
