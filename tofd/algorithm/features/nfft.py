"""NFFT path (paper section 2.2): scale-invariant generalized eccentricities of the back-projected foreground.

Per frame:
1. back-project the foreground pixels (radial range) to camera-frame points x, y, z (metres), turned into
   the segmentation's face frame when given (segmentation.Foreground.rotation: z along the face's normal);
2. scale x, y by the field of view at the equivalence range e (width W e / fx, height H e / fy), so that
   the field of view at e maps onto [-1/2, 1/2)^2; shift the centroid to 0; drop points outside (their
   features are NaN); offset z so its maximum is 0;
3. solve for Fourier coefficients f on the N x N frequency grid with z_j ~ sum_k f_k exp(2 pi i k.x_j);
4. multiply by the transfer functions (transfer.py, mode k <-> k / L cycles per metre) and evaluate the
   filtered fields c0, c2, s2 back at the points with a forward NUFFT; eps0 = c0^2, eps2 = c2^2 + s2^2.

Regularisation (step 3). The paper's minimum-norm inverse is ill-posed on a face patch (the modes living
outside the patch are undetermined; see design/nfft_notes.md). We solve the damped normal equations
    (A^H A + lambda I) f = A^H z,   lambda = damping * (points per unit area of the square),
the points per unit area being 1 / mean pixel footprint, (z/fx)(z/fy) / (Lx Ly). Well-sampled modes of
A^H A have eigenvalues ~ that density, so damping (0.01) is the relative shrinkage of the resolved part:
the bias is the same for every patch size and distance (scale-invariant), the system's condition number
is ~1/damping whatever the patch, and the field is pulled to 0 (= max z, like the FFT path's background)
where there are no points. nfft_notes' lambda = 0.01 M shrinks less on small patches and needed 50-100
CG iterations on 250-1800-point face patches where this needs 12-30 (measured, rendered faces).
Larger damping smooths range noise more but shrinks the features unevenly: sphere apex eps0 spread over
0.3-0.9 m 1.9 / 4.3 / 12.4 % and FFT/NFFT at e 1.009 / 1.015 / 1.038 at damping 0.01 / 0.03 / 0.1
(`tofd experiment sphere`), while the detector's cross-validated EER moved by about one frame
(bench/tune_detector.py --grid damping, 72 frames per subject: NFFT range 0.7 / 0.4 / 0.4 / 0.3 / 0.3 % at
0.003 / 0.01 / 0.03 / 0.1 / 0.3), so 0.01 stays.

Stopping. CG stops when the residual weighted by A(rho) (the filters' band) falls below cg_tolerance
relative to the weighted right-hand side: smooth surfaces put most of A^H z at low frequencies that
the filters ignore, and the plain residual stopped the sphere after 4-7 iterations with eps0 off by 15 %.
At the default 1e-4: faces 17-31 iterations, eps0 within 0.1 % of the converged value.

Solver. A^H A is Toeplitz, (A^H A f)_k = sum_l K_{k-l} f_l with K_m = sum_j exp(-2 pi i m.x_j). One
finufft type-1 per frame gives K on the 2N x 2N grid (and A^H z with it: n_trans=2); then every CG
iteration is a circulant convolution, i.e. one real FFT pair of size 2N x 2N. The unpaired Nyquist row and
column (k = -N/2) are held at zero, so the unknowns, kernel and fields are Hermitian/real: CG works on the
half spectrum (kx >= 0) with real FFTs. A forward type-2 NUFFT (n_trans=2) evaluates c0 + i c2 and s2.
finufft plans are made once (nthreads=1) and only get new points per frame.

Amplitude (`features(..., amplitude=...)`): the amplitude at the same points, normalised like the FFT path's,
is a second surface on the same kernel (one more CG solve): scale-invariant amplitude features for the NFFT
detector variant.
"""

from __future__ import annotations

from dataclasses import dataclass

import finufft
import numpy as np
import scipy.fft as sfft

from drivers.intrinsics import Intrinsics
from tofd.algorithm.features.eccentricity import Eccentricities
from tofd.algorithm.features.fft import check_frame
from tofd.algorithm.features.transfer import transfer_functions, unit_square_m
from tofd.algorithm.params import FeatureConfig


def _upsampfac(eps: float) -> float:
    """finufft's small oversampling (much faster here) where it reaches the requested precision."""
    return 1.25 if eps >= 1e-9 else 2.0


@dataclass(frozen=True, slots=True)
class UnitSquarePoints:
    """Foreground points prepared for the NFFT: x, y in [-1/2, 1/2), z in metres (max 0), pixel index."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    index: np.ndarray  # flat pixel index of each kept point
    damping: float  # lambda for these points


class NFFTFeatures:
    """Plans, transfer grids and buffers for one camera geometry and config; call per frame."""

    def __init__(self, intrinsics: Intrinsics, cfg: FeatureConfig):
        self.intrinsics, self.cfg = intrinsics, cfg
        n = cfg.grid_size
        self._n, self._h = n, n // 2
        self._rays = intrinsics.unit_rays()
        self._square = unit_square_m(intrinsics, cfg.equivalence_range_m)
        k = sfft.fftfreq(n, 1.0 / n)  # integer modes in FFT order (finufft modeord=1)
        c0, c2, s2 = transfer_functions(k[None, :] / self._square[0], k[:, None] / self._square[1],
                                        cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
        self._filters = np.stack([c0 + 1j * c2, s2 + 0j])  # (2, N, N) rows ky, columns kx
        # stopping weight: A(rho) (= |C0|) on the compact half spectrum, rows ky, columns kx = 0 .. N/2 - 1
        self._band = np.concatenate((c0[: self._h, : self._h], c0[n - self._h + 1:, : self._h]))
        single = cfg.cg_precision == "single"
        self._real: type[np.floating] = np.float32 if single else np.float64
        self._complex: type[np.complexfloating] = np.complex64 if single else np.complex128
        self._band = self._band.astype(self._real)
        self._padded = np.zeros((2 * n, n + 1), self._complex)  # half spectrum of the 2N circulant
        self._neg_rows = (-np.arange(n)) % n
        self._neg_cols_src = n - np.arange(n - self._h + 1, n)
        self._plan_options = dict(eps=cfg.nufft_eps, modeord=1, nthreads=1, upsampfac=_upsampfac(cfg.nufft_eps))
        self._plans: dict[int, tuple[finufft.Plan, finufft.Plan]] = {}

    def _plans_for(self, surfaces: int) -> tuple[finufft.Plan, finufft.Plan]:
        """finufft plans (made once) for `surfaces` value sets on shared points: type 1 onto the 2N grid (the
        kernel and each right-hand side), type 2 back to the points (c0 + i c2 and s2 of each)."""
        if surfaces not in self._plans:
            n, opts = self._n, self._plan_options
            self._plans[surfaces] = (finufft.Plan(1, (2 * n, 2 * n), n_trans=1 + surfaces, isign=-1, **opts),
                                     finufft.Plan(2, (n, n), n_trans=2 * surfaces, isign=1, **opts))
        return self._plans[surfaces]

    def unit_square_points(self, range_m: np.ndarray, mask: np.ndarray,
                           rotation: np.ndarray | None = None) -> UnitSquarePoints:
        """Steps 1-2: the kept points in [-1/2, 1/2)^2 with max z = 0, and the damping for them.

        rotation: camera -> face frame (tofd.algorithm.segmentation.Foreground), applied to the points first.
        """
        flat = np.flatnonzero(mask)
        pts = self._rays.reshape(-1, 3)[flat] * range_m.reshape(-1)[flat, None].astype(np.float64)
        if rotation is not None:
            pts = pts @ rotation.T
        x = pts[:, 0] / self._square[0]
        y = pts[:, 1] / self._square[1]
        x -= x.mean()
        y -= y.mean()
        keep = (x >= -0.5) & (x < 0.5) & (y >= -0.5) & (y < 0.5)
        z = pts[keep, 2]
        # points per unit area of the square: 1 / mean pixel footprint, (z/fx)(z/fy) m^2 over Lx Ly
        footprint = np.mean(z * z) / (self.intrinsics.fx * self.intrinsics.fy * self._square[0] * self._square[1])
        return UnitSquarePoints(x[keep], y[keep], z - z.max() if z.size else z, flat[keep],
                                self.cfg.damping / footprint if z.size else 0.0)

    def range_features(self, range_m: np.ndarray, mask: np.ndarray,
                       rotation: np.ndarray | None = None) -> Eccentricities:
        """eps0, eps2 (metres^2) per foreground pixel of a radial range map; NaN elsewhere (rotation: see
        unit_square_points)."""
        return self.features(range_m, mask, rotation)[0]

    def features(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None,
                 amplitude: np.ndarray | None = None) -> tuple[Eccentricities, Eccentricities | None]:
        """Range features (range_features) and, given the amplitude image, its features at the same points.

        Amplitude: divided by its median over the points and offset so its minimum is 0 (the FFT path's
        normalisation and background, tofd.algorithm.features.fft.FFTFeatures.amplitude_features), then filtered like
        z(x, y): scale-invariant like the range features, where the FFT amplitude features change with distance.
        Both surfaces share the points, hence one Toeplitz kernel; each has its own CG solve.
        """
        check_frame(range_m, mask, self.intrinsics, "range_m")
        if amplitude is not None:
            check_frame(amplitude, mask, self.intrinsics, "amplitude")
        empty = Eccentricities.empty(self.intrinsics.shape)
        pts = self.unit_square_points(range_m, mask, rotation) if mask.any() else None
        if pts is None or pts.index.size == 0:
            return empty, (None if amplitude is None else Eccentricities.empty(self.intrinsics.shape))
        values = [pts.z]
        if amplitude is not None:
            a = amplitude.reshape(-1)[pts.index].astype(np.float64)
            scale = float(np.median(a))
            values.append((a - a.min()) / scale if scale > 0 else np.zeros_like(a))
        fields = self.fields(pts.x, pts.y, np.stack(values), pts.damping)
        maps = [self._maps(pts.index, *f) for f in fields]
        return maps[0], (maps[1] if amplitude is not None else None)

    def _maps(self, index: np.ndarray, c0: np.ndarray, c2: np.ndarray, s2: np.ndarray, iterations: int,
              residual: float) -> Eccentricities:
        """(H, W) eps0, eps2 maps from the fields at the points `index` (flat pixel indices); NaN elsewhere."""
        eps0 = np.full(self.intrinsics.shape, np.nan, np.float32)
        eps2 = np.full(self.intrinsics.shape, np.nan, np.float32)
        eps0.reshape(-1)[index] = c0 * c0
        eps2.reshape(-1)[index] = c2 * c2 + s2 * s2
        return Eccentricities(eps0, eps2, iterations, residual)

    def fields(self, x: np.ndarray, y: np.ndarray, values: np.ndarray,
               lam: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int, float]]:
        """Steps 3-4 for each row of `values` (V, M) sampled at the points x, y in [-1/2, 1/2)^2, damping lam:
        per row (c0, c2, s2 at the points, CG iterations, final relative residual)."""
        n, h = self._n, self._h
        values = np.atleast_2d(values)
        type1, type2 = self._plans_for(len(values))
        ty, tx = 2 * np.pi * y, 2 * np.pi * x
        type1.setpts(ty, tx)
        strengths = np.ones((1 + len(values), x.size), np.complex128)
        strengths[1:] = values
        kernel_and_rhs = type1.execute(strengths)
        kernel = kernel_and_rhs[0, :, : n + 1].copy()
        kernel[n, :] = 0  # the unpaired -N row and column never enter (A^H A f)_k for |k| < N/2
        kernel[:, n] = 0
        circulant = (sfft.irfft2(kernel, s=(2 * n, 2 * n), workers=1) * float(4 * n * n)).astype(self._real)
        solved = []
        for rhs_grid in kernel_and_rhs[1:]:
            rhs = np.concatenate((rhs_grid[:h, :h], rhs_grid[2 * n - h + 1:, :h])).astype(self._complex)
            solved.append(self._solve(circulant, rhs, lam))
        type2.setpts(ty, tx)
        out = type2.execute(np.concatenate([self._filters * self._hermitian_full(f) for f, _, _ in solved]))
        return [(out[2 * i].real, out[2 * i].imag, out[2 * i + 1].real, it, res)
                for i, (_, it, res) in enumerate(solved)]

    def _normal(self, circulant: np.ndarray, v: np.ndarray, lam: float, out: np.ndarray) -> np.ndarray:
        """out = (A^H A + lam I) v on the compact half spectrum, via the 2N circulant (one real FFT pair)."""
        n, h = self._n, self._h
        padded = self._padded
        padded[:h, :h] = v[:h]
        padded[2 * n - h + 1:, :h] = v[h:]
        grid = sfft.irfft2(padded, s=(2 * n, 2 * n), workers=1)
        grid *= circulant
        spec = sfft.rfft2(grid, workers=1)
        out[:h] = spec[:h, :h]
        out[h:] = spec[2 * n - h + 1:, :h]
        out += lam * v
        return out

    @staticmethod
    def _dot(a: np.ndarray, b: np.ndarray) -> float:
        """Re <a, b> of the full Hermitian spectra, from their halves (kx > 0 counted twice)."""
        return 2.0 * np.vdot(a, b).real - np.vdot(a[:, 0], b[:, 0]).real

    def _solve(self, circulant: np.ndarray, rhs: np.ndarray, lam: float) -> tuple[np.ndarray, int, float]:
        """Conjugate gradients on the damped normal equations; returns (f, iterations, relative residual)."""
        x = np.zeros_like(rhs)
        r = rhs.copy()
        p = r.copy()
        q = np.empty_like(rhs)
        band = self._band
        rr = self._dot(r, r)
        b_band = np.sqrt(self._dot(band * r, band * r))
        if b_band == 0:
            return x, 0, 0.0
        tol2 = (self.cfg.cg_tolerance * b_band) ** 2
        r_band2 = b_band**2
        iterations = 0
        while iterations < self.cfg.cg_max_iterations and r_band2 > tol2:
            self._normal(circulant, p, lam, q)
            alpha = rr / self._dot(p, q)
            x += alpha * p
            r -= alpha * q
            rr, rr_old = self._dot(r, r), rr
            p *= rr / rr_old
            p += r
            r_band2 = self._dot(band * r, band * r)
            iterations += 1
        return x, iterations, float(np.sqrt(r_band2) / b_band)

    def _hermitian_full(self, half: np.ndarray) -> np.ndarray:
        """(N, N) FFT-ordered spectrum from the compact half (kx >= 0) by Hermitian symmetry."""
        n, h = self._n, self._h
        full = np.zeros((n, n), np.complex128)
        full[:h, :h] = half[:h]
        full[n - h + 1:, :h] = half[h:]
        full[:, n - h + 1:] = np.conj(full[np.ix_(self._neg_rows, self._neg_cols_src)])
        return full
