"""NFFT path (paper section 2.2): scale-invariant generalized eccentricities of the back-projected foreground.

Per frame:
1. back-project the foreground pixels (radial range) to camera-frame points x, y, z (metres), turned into
   the segmentation's face frame when given (segmentation.Foreground.rotation: z along the face's normal);
2. scale x, y by the patch (FeatureConfig.patch_width_m Lx, patch_height_m Ly, metres), so that a patch centred
   on the points' centroid maps onto [-1/2, 1/2)^2; drop points outside (their features are NaN) and points
   without a finite positive range (holes); offset z so its maximum is 0;
3. solve for Fourier coefficients f on the N x N frequency grid with z_j ~ sum_k f_k exp(2 pi i k.x_j);
4. multiply by the transfer functions (operators.py, mode k <-> k / L cycles per metre) and evaluate the
   filtered fields c0, c2, s2 back at the points with a forward NUFFT; eps0 = c0^2, eps2 = c2^2 + s2^2.

Everything is set in metres, nothing in pixels or fields of view, so every camera that samples the surface finely
enough gives the same features; one that does not (sampling.py) is refused with SamplingError.

Regularisation (step 3). The paper's minimum-norm inverse is ill-posed on a face patch (the modes outside the
patch are undetermined), so we solve the damped normal equations
    (A^H A + lambda I) f = A^H z,   lambda = damping * (points per unit area of the square),
the points per unit area being Lx Ly / mean pixel footprint (z/fx)(z/fy). Well-sampled modes of A^H A have
eigenvalues ~ that density, so `damping` is the same relative shrinkage for every camera, patch and distance: the
problem is min |z - f|^2 + damping |f|^2, both integrated over the patch in square metres, and the field is
pulled to 0 (= max z, like the FFT path's background) where there are no points.
The sphere experiment (`tofd experiment sphere`) measures what larger damping costs in invariance.

Solver (normal_equations.py). One finufft type-1 per frame gives K_m = sum_j exp(-2 pi i m.x_j) on the
2N x 2N grid and A^H z with it, both from the one complex transform of 1 + i z (spectra of real data are
Hermitian, so the two separate: real_pair_spectra); A^H A is Toeplitz with kernel K, so every CG iteration is a
circulant convolution (one pruned real FFT pair of size 2N) on the half spectrum (kx >= 0; the unpaired
Nyquist row and column held at zero keep unknowns and fields Hermitian/real). CG stops on the residual
weighted by A(rho) (cg_tolerance; the default keeps eps0 within 1 % of the converged value wherever it is
at least a tenth of its peak: bench/bench_features.py). A forward type-2 NUFFT evaluates the fields, two real ones
per complex transform where the operators are Hermitian (c0 + i c2 and s2). finufft plans, the solver and the
grids they write are made once (nthreads=1); a frame only sets new points and kernel, and the steps between the
transforms are compiled loops (spectra_kernels.py).

Amplitude (`features(..., amplitude=...)`): the amplitude at the same points, normalised like the FFT path's,
is a second surface on the same kernel (a second right-hand side in the same CG batch): scale-invariant
amplitude features for the NFFT detector variant.
"""

from __future__ import annotations

from dataclasses import dataclass

import finufft
import numpy as np
import scipy.fft as sfft

from tofd.algorithm.band import radial_tuning
from tofd.algorithm.features.compiled import compiled
from tofd.algorithm.features.eccentricity import Eccentricities, MapsOut
from tofd.algorithm.features.fft import check_frame, usable
from tofd.algorithm.features.normal_equations import DampedNormalEquations, load_kernels, norm_weights, solve
from tofd.algorithm.features.operators import Transfer, eccentricity_transfer, evaluate
from tofd.algorithm.features.sampling import check_sampling
from tofd.algorithm.params import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics

SINGLE_NUFFT_EPS = 2e-5  # finufft's float32 precision floor at upsampfac 1.25 (below it narrows its kernel and warns)


def _upsampfac(nufft_type: int, eps: float) -> float:
    """finufft's oversampling: type 1 (onto the 2N grid) is faster with the small 1.25 where it reaches the requested
    precision, type 2 (from the N grid, whose FFT is small) with 2.0 and its narrower kernel."""
    return 1.25 if nufft_type == 1 and eps >= 1e-9 else 2.0


_IDENTITY = np.eye(3)


def _load_spectra_kernels(dtype: type[np.complexfloating]) -> None:
    """Load spectra_kernels' loops for complex `dtype` now (compiling them the first time on a machine), with the
    argument types the frames pass, not in the first frame: a live run's first frames would wait for it."""
    kernels, real = compiled("spectra_kernels"), np.finfo(dtype).dtype
    kernels.pack_pairs(np.ones((1, 1)), np.ones(1), np.empty((1, 1), dtype))
    kernels.separate_pairs(np.zeros((1, 2, 2), dtype), np.ones(1, real), np.empty((1, 2, 2), dtype))
    kernels.hermitian_full(np.zeros((1, 1), dtype), np.empty((2, 2), dtype))


@dataclass(frozen=True, slots=True)
class UnitSquarePoints:
    """Foreground points prepared for the NFFT: x, y in [-1/2, 1/2), z in metres (max 0), pixel index."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    index: np.ndarray  # flat pixel index of each kept point
    valid: int  # points of the mask with a finite range > 0, kept or outside the patch
    damping: float  # lambda for these points
    rms_range_m: float  # root mean square of the points' range, metres (their pixel pitch is about this / f)


@dataclass(frozen=True, slots=True)
class _Transforms:
    """finufft plans for a number of surfaces and the arrays they reuse: type 1's output grids (pairs, 2N, 2N) and
    type 2's input modes (surfaces x packed operators, N, N)."""

    type1: finufft.Plan
    type2: finufft.Plan
    grids: np.ndarray
    modes: np.ndarray


@dataclass(frozen=True, slots=True)
class SurfaceFields:
    """One surface's filtered fields at the points: values (K, M), float64 for Hermitian operators else complex;
    iterations: CG iterations; residual: final relative band-weighted CG residual."""

    values: np.ndarray
    iterations: int
    residual: float


def real_pair_spectra(type1: finufft.Plan, rows: np.ndarray, columns: int, grids: np.ndarray | None = None
                      ) -> np.ndarray:
    """(R, 2N, columns) type-1 spectra (first `columns` kx) of R real strength sets, two per complex transform.

    F(u + i v) = F(u) + i F(v) and F(u)_-m = conj F(u)_m for real u, so F(u) = (G + G*_-m) / 2 and
    F(v) = (G - G*_-m) / 2i, except on the unpaired m = -N row and column (their mirror is off the grid; the
    solver never uses them). Each set is scaled to mean |value| 1 first so both share finufft's precision.
    type1: n_trans = ceil(R / 2), onto a 2N x 2N grid in FFT order; grids: its (ceil(R / 2), 2N, 2N) output G to
    reuse (a new array if None).
    """
    kernels = compiled("spectra_kernels")
    scale = np.mean(np.abs(rows), axis=1)
    scale[scale == 0] = 1.0
    strengths = np.empty(((len(rows) + 1) // 2, rows.shape[1]), type1.dtype)
    kernels.pack_pairs(rows, scale, strengths)
    grids = type1.execute(strengths, out=grids)
    out = np.empty((len(rows), grids.shape[-2], columns), type1.dtype)
    kernels.separate_pairs(grids, (0.5 * scale).astype(np.finfo(out.dtype).dtype), out)  # the halves, the sets' scales
    return out


class NFFTFeatures:
    """Plans, transfer grids and buffers for one camera geometry and config; call per frame, one frame at a time (the
    plans and buffers are the instance's: one instance per worker process or thread).

    transfer: the operators to apply (tofd.algorithm.features.operators; default the eccentricity filters
    [C0, C2, S2], which range_features and features need), at the mode frequencies k / patch side.
    """

    def __init__(self, intrinsics: Intrinsics, cfg: FeatureConfig, transfer: Transfer | None = None):
        self.intrinsics, self.cfg = intrinsics, cfg
        n = cfg.grid_size
        self._n, self._h = n, n // 2
        self._ray_columns = np.ascontiguousarray(intrinsics.unit_rays().reshape(-1, 3).T)  # (3, H W): takes are fast
        self._square = (cfg.patch_width_m, cfg.patch_height_m)
        k = sfft.fftfreq(n, 1.0 / n)  # integer modes in FFT order (finufft modeord=1)
        kx, ky = k[None, :] / self._square[0], k[:, None] / self._square[1]
        self._eccentricity = transfer is None
        operators = evaluate(transfer or eccentricity_transfer(cfg), kx, ky)  # (K, N, N) rows ky, columns kx
        self._hermitian, self._count, self.stacked = operators.hermitian, len(operators), operators.stacked
        v = operators.values
        magnitude = np.abs(v).reshape(len(v), -1)
        beyond = (np.hypot(kx, ky) > cfg.band_edge_per_m).reshape(-1)
        peak = np.maximum(magnitude.max(axis=1), np.finfo(np.float64).tiny)
        self.beyond_band = float(np.max(magnitude[:, beyond].max(axis=1, initial=0.0) / peak))
        """The largest magnitude of an operator on the modes beyond the band edge, as a fraction of its peak."""
        self.last_points = (0, 0)
        """(kept, valid): the last frame's points inside the patch, and its mask's points with a usable range."""
        # Hermitian operators give real fields: two per complex transform (v0 + i v1, v2 + i v3, ...)
        filters = np.stack([v[i] + 1j * v[i + 1] if i + 1 < len(v) else v[i] + 0j for i in range(0, len(v), 2)]
                           ) if self._hermitian else v.astype(np.complex128)
        # stopping weight: A(rho) on the compact half spectrum, rows ky, columns kx = 0 .. N/2 - 1
        a = radial_tuning(np.hypot(kx, ky), cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
        band = np.concatenate((a[: self._h, : self._h], a[n - self._h + 1:, : self._h]))
        single = cfg.cg_precision == "single"
        self._real: type[np.floating] = np.float32 if single else np.float64
        self._complex: type[np.complexfloating] = np.complex64 if single else np.complex128
        self._norm_weights = norm_weights(band.astype(self._real))  # CG's, made once rather than every frame
        self._filters = filters.astype(self._complex)
        self._full = np.empty((n, n), self._complex)  # a solution's spectrum, filtered into type 2's modes
        eps = max(cfg.nufft_eps, SINGLE_NUFFT_EPS) if single else cfg.nufft_eps
        self._nufft_eps = eps
        # spread_sort=0: the points come in pixel order, local enough; finufft's bin sort costs more than it saves
        self._plan_options = dict(modeord=1, nthreads=1, dtype=self._complex, spread_sort=0)
        self._plans: dict[int, _Transforms] = {}
        self._system = DampedNormalEquations(n, self._real, self._complex)
        load_kernels(self._complex)
        _load_spectra_kernels(self._complex)
        self.unit_square_points(np.ones(intrinsics.shape), np.zeros(intrinsics.shape, bool))  # load its loop now

    def _plans_for(self, surfaces: int) -> _Transforms:
        """finufft plans (made once) for `surfaces` value sets on shared points: type 1 onto the 2N grid (the
        kernel and each right-hand side, two real sets per complex transform), type 2 back to the points
        (the packed operators of each)."""
        if surfaces not in self._plans:
            n, opts, eps = self._n, self._plan_options, self._nufft_eps
            pairs = (2 + surfaces) // 2
            type1 = finufft.Plan(1, (2 * n, 2 * n), n_trans=pairs, isign=-1, eps=eps, upsampfac=_upsampfac(1, eps),
                                 **opts)
            type2 = finufft.Plan(2, (n, n), n_trans=len(self._filters) * surfaces, isign=1, eps=eps,
                                 upsampfac=_upsampfac(2, eps), **opts)
            self._plans[surfaces] = _Transforms(type1, type2, np.empty((pairs, 2 * n, 2 * n), self._complex),
                                                np.empty((len(self._filters) * surfaces, n, n), self._complex))
        return self._plans[surfaces]

    def unit_square_points(self, range_m: np.ndarray, mask: np.ndarray,
                           rotation: np.ndarray | None = None) -> UnitSquarePoints:
        """Steps 1-2: the kept points in [-1/2, 1/2)^2 with max z = 0, and the damping for them.

        Pixels of the mask whose range is NaN, inf or <= 0 are left out (holes). rotation: camera -> face frame
        (tofd.algorithm.segmentation.Foreground), applied to the points first.
        """
        flat = np.flatnonzero(mask)
        turn = _IDENTITY if rotation is None else np.ascontiguousarray(rotation, np.float64)
        ranges = np.take(range_m.reshape(-1), flat).astype(np.float64, copy=False)
        patch_points = compiled("patch_points").patch_points
        x, y, z, index, mean_zz, mean_rr = patch_points(flat, ranges, self._ray_columns, turn, *self._square)
        valid = int(np.count_nonzero(ranges > 0)) - int(np.count_nonzero(ranges == np.inf))  # NaN is neither
        if not z.size:
            return UnitSquarePoints(x, y, z, index, valid, 0.0, float("nan"))
        # points per unit area of the square: 1 / mean pixel footprint, (z/fx)(z/fy) m^2 over Lx Ly
        footprint = mean_zz / (self.intrinsics.fx * self.intrinsics.fy * self._square[0] * self._square[1])
        return UnitSquarePoints(x, y, z - z.max(), index, valid, self.cfg.damping / footprint,
                                float(np.sqrt(mean_rr)))

    def range_features(self, range_m: np.ndarray, mask: np.ndarray,
                       rotation: np.ndarray | None = None) -> Eccentricities:
        """eps0, eps2 (metres^2) per foreground pixel of a radial range map; NaN elsewhere and at holes (rotation:
        see unit_square_points)."""
        return self.features(range_m, mask, rotation)[0]

    def filtered(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
        """(K, H, W) fields of the operators on the surface of a radial range map, float64 where the operators are
        Hermitian, else complex128; NaN outside the mask, at holes and at points outside the patch."""
        check_frame(range_m, mask, self.intrinsics, "range_m")
        pts = self._checked_points(range_m, mask, rotation)
        out = np.full((self._count, *self.intrinsics.shape), np.nan, np.float64 if self._hermitian else np.complex128)
        if pts.index.size:
            out.reshape(self._count, -1)[:, pts.index] = self.fields(pts.x, pts.y, pts.z[None], pts.damping)[0].values
        return out

    def features(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None,
                 amplitude: np.ndarray | None = None, out: MapsOut | None = None,
                 amplitude_out: MapsOut | None = None) -> tuple[Eccentricities, Eccentricities | None]:
        """Range features (range_features) and, given the amplitude image, its features at the same points.

        out, amplitude_out: two (H, W) float32 arrays each that the range and amplitude maps are written into (and
        returned as), e.g. a worker's shared memory; new arrays where not given.

        Amplitude: divided by its median over the points and offset so its minimum is 0 (the FFT path's
        normalisation and background, tofd.algorithm.features.fft.FFTFeatures.amplitude_features), then filtered like
        z(x, y): scale-invariant like the range features, where the FFT amplitude features change with distance.
        Both surfaces share the points, hence one Toeplitz kernel; each has its own CG solve. Points whose
        amplitude is not finite are left out of both.

        Raises SamplingError (a ValueError) if the pixels at the foreground's range cannot carry the band
        (tofd.algorithm.features.sampling).
        """
        if not self._eccentricity:
            raise ValueError("eccentricities need the default operators; this instance applies a user transfer "
                             "(use filtered)")
        check_frame(range_m, mask, self.intrinsics, "range_m")
        if amplitude is not None:
            check_frame(amplitude, mask, self.intrinsics, "amplitude")
            mask = usable(amplitude, mask, positive=False)
        pts = self._checked_points(range_m, mask, rotation)
        if pts.index.size == 0:
            empty = Eccentricities.empty(self.intrinsics.shape, out=out)
            return empty, (None if amplitude is None else Eccentricities.empty(self.intrinsics.shape,
                                                                                out=amplitude_out))
        values = [pts.z]
        if amplitude is not None:
            a = amplitude.reshape(-1)[pts.index].astype(np.float64)
            scale = float(np.median(a))
            values.append((a - a.min()) / scale if scale > 0 else np.zeros_like(a))
        maps = [self._maps(pts.index, f, o) for f, o in zip(self.fields(pts.x, pts.y, np.stack(values), pts.damping),
                                                             (out, amplitude_out), strict=False)]
        return maps[0], (maps[1] if amplitude is not None else None)

    def _checked_points(self, range_m: np.ndarray, mask: np.ndarray,
                        rotation: np.ndarray | None) -> UnitSquarePoints:
        """unit_square_points, refused (SamplingError) where the pixels cannot carry the band."""
        pts = self.unit_square_points(range_m, mask, rotation)
        self.last_points = (int(pts.index.size), pts.valid)
        if pts.index.size:
            check_sampling(pts.rms_range_m, self.intrinsics, self.cfg)
        return pts

    def _maps(self, index: np.ndarray, fields: SurfaceFields, out: MapsOut | None) -> Eccentricities:
        """(H, W) eps0, eps2 maps (in `out` if given) from the fields [c0, c2, s2] at the points `index` (flat pixel
        indices); NaN elsewhere."""
        c0, c2, s2 = fields.values
        maps = Eccentricities.empty(self.intrinsics.shape, fields.iterations, fields.residual, out)
        maps.eps0.reshape(-1)[index] = c0 * c0
        maps.eps2.reshape(-1)[index] = c2 * c2 + s2 * s2
        return maps

    def fields(self, x: np.ndarray, y: np.ndarray, values: np.ndarray, lam: float) -> list[SurfaceFields]:
        """Steps 3-4 for each row of `values` (V, M) sampled at the points x, y in [-1/2, 1/2)^2, damping lam:
        per row the K operators' fields at the points, CG iterations and final relative residual."""
        n, h = self._n, self._h
        values = np.atleast_2d(values)
        plans = self._plans_for(len(values))
        ty, tx = (2 * np.pi * y).astype(self._real), (2 * np.pi * x).astype(self._real)
        plans.type1.setpts(ty, tx)
        kernel_and_rhs = real_pair_spectra(plans.type1, np.concatenate((np.ones((1, x.size)), values)), n + 1,
                                           plans.grids)
        system = self._system.set_kernel(kernel_and_rhs[0], lam)
        grids = kernel_and_rhs[1:]
        rhs = np.concatenate((grids[:, :h, :h], grids[:, 2 * n - h + 1:, :h]), axis=1)
        solved = solve(system, rhs, self._norm_weights, self.cfg.cg_tolerance, self.cfg.cg_max_iterations)
        packed = len(self._filters)
        for s, modes in zip(solved, plans.modes.reshape(len(solved), packed, n, n), strict=True):
            compiled("spectra_kernels").hermitian_full(s.f, self._full)
            np.multiply(self._filters, self._full, out=modes)
        plans.type2.setpts(ty, tx)
        out = plans.type2.execute(plans.modes)
        return [SurfaceFields(self._unpack(out[i * packed:(i + 1) * packed]), s.iterations, s.residual)
                for i, s in enumerate(solved)]

    def _unpack(self, packed: np.ndarray) -> np.ndarray:
        """(K, M) fields from one surface's transforms (P, M): Hermitian operators were packed two per transform."""
        if not self._hermitian:
            return packed.astype(np.complex128)
        return np.stack([part for p in packed for part in (p.real, p.imag)][: self._count])
