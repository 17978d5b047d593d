"""Transfer functions of the generalized eccentricities, in physical frequencies (cycles per metre at e).

C_n(k) = i^n A(rho) cos(n theta),  S_n(k) = i^n A(rho) sin(n theta),  n = 0, 2,
with rho = |k| in cycles per metre and theta the angle of k (x right, y down). For n = 0 and 2 the factor
i^n is real (+1, -1), so all three non-trivial filters are real and even in k: C0 = A, C2 = -A cos 2theta,
S2 = -A sin 2theta (S0 = 0). Filtering a real surface with them gives real fields c0, c2, s2 and
eps0 = c0^2, eps2 = c2^2 + s2^2 (metres^2 on range, squared input units otherwise).

A(rho) = T(rho) G(rho): the radial tuning T(rho) = (rho/rho0)^2 exp(1 - rho^2 / rho0^2) (peak 1 at rho0)
times a Gaussian low-pass G(rho) = exp(-rho^2 / (2 sigma^2)) that keeps the filter inside the band of
the NFFT grid. T ~ rho^2 near 0 (a Laplacian of Gaussian in space) makes the filter local: constant and
linear surfaces (any plane) give exactly 0 and a sphere's apex response depends only on its curvature.
nfft_notes' T = (rho/rho0) exp(1/2 - rho^2/(2 rho0^2)) is ~|rho| at 0, a long-tailed kernel whose apex
response depends on the sphere's rim and background: measured NFFT eps0 at a 0.1 m sphere's apex varied
by 20 % over 0.3-0.9 m with it and by 0.2 % with rho^2 (converged CG). Default rho0 = 35 /m (spatial
Gaussian ~ 1 / (pi sqrt(2) rho0) = 6.4 mm, the nose tip's scale), with the default segmentation, chosen by
leave-one-subject-out cross-validation on the training subjects (bench/tune_detector.py --grid band, band2):
mean NFFT range-only EER 1.4 % at rho0 = 35 /m against 3.3 % at 30, 1.4-2.5 % at 40, 3-5 % at 45 and 17-21 % at
20 /m. The NFFT grid must hold the band: at rho0 = 35 with a 64 x 64 grid (Nyquist 73 /m at e = 0.5 m, where A
is still 5 % of its peak) a sphere's apex eps2 (0 in theory) rose to 1e-6 eps0 and a plane tilted 60 deg left
eps0 at 2 % of a sphere's; the default 80 x 80 grid (Nyquist 91 /m) gives 4e-9 and 0.7 % for 25 % more time.

Both feature paths call `transfer_functions` with physical frequencies, so they apply the same filter:
- FFT path: pixel frequency (cycles/pixel) times f/e (a pixel spans e/f metres at the equivalence range);
- NFFT path: mode index k divided by the width of the unit square in metres, L = (image width / f) * e.
"""

from __future__ import annotations

import numpy as np

from drivers.intrinsics import Intrinsics
from tofd.algorithm.params import FeatureConfig


def radial_tuning(rho_per_m: np.ndarray, cfg: FeatureConfig) -> np.ndarray:
    """A(rho): radial tuning times Gaussian low-pass, rho in cycles per metre."""
    r2 = (np.asarray(rho_per_m, dtype=np.float64) / cfg.tuning_frequency_per_m) ** 2
    lowpass = np.exp(-0.5 * (np.asarray(rho_per_m) / cfg.lowpass_sigma_per_m) ** 2)
    return r2 * np.exp(1.0 - r2) * lowpass


def transfer_functions(kx_per_m: np.ndarray, ky_per_m: np.ndarray, cfg: FeatureConfig) -> np.ndarray:
    """(3, ...) real filters [C0, C2, S2] at physical frequencies (kx, ky) in cycles per metre (broadcast)."""
    kx, ky = np.broadcast_arrays(np.asarray(kx_per_m, dtype=np.float64), np.asarray(ky_per_m, dtype=np.float64))
    a = radial_tuning(np.hypot(kx, ky), cfg)
    theta2 = 2 * np.arctan2(ky, kx)
    return np.stack([a, -a * np.cos(theta2), -a * np.sin(theta2)])


def pixel_frequencies_per_m(pixel_freq_x: np.ndarray, pixel_freq_y: np.ndarray, intrinsics: Intrinsics,
                            equivalence_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """FFT path: cycles/pixel -> cycles/metre at the equivalence range (times f/e per axis)."""
    return (np.asarray(pixel_freq_x) * intrinsics.fx / equivalence_range_m,
            np.asarray(pixel_freq_y) * intrinsics.fy / equivalence_range_m)


def unit_square_m(intrinsics: Intrinsics, equivalence_range_m: float) -> tuple[float, float]:
    """NFFT path: width and height in metres of the field of view at e, mapped onto [-1/2, 1/2)^2."""
    return (intrinsics.width / intrinsics.fx * equivalence_range_m,
            intrinsics.height / intrinsics.fy * equivalence_range_m)
