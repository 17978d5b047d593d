"""The public functions on the user's own arrays: eccentricities, any surface operator, range from depth.

Array in, array out, in the style of scikit-image: every function checks its inputs here (one ValueError naming
the argument) and runs the same feature code as the pipeline (tofd.algorithm.features). Units: metres for range,
cycles per metre for spatial frequencies, pixels for intrinsics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.features import Eccentricities, Transfer
from tofd.algorithm.features.transfer import eccentricity_filters
from tofd.algorithm.params import FeatureConfig
from tofd.api_inputs import check_config, check_intrinsics, checked_image
from tofd.drivers.intrinsics import Intrinsics
from tofd.plan import FeaturePlan, Method, cached_plan, check_method


def eccentricities(range_m: np.ndarray, intrinsics: Intrinsics, *, mask: np.ndarray | None = None,
                   method: Method = "nfft", config: FeatureConfig | None = None) -> Eccentricities:
    """Generalized eccentricities eps0 and eps2 of a range image (Haker et al. 2008).

    eps0 responds to the surface's curvature (at the apex of a sphere of radius R it is about
    (2/R)^2 (e / (2 pi rho0)^2)^2, e = exp(1), rho0 = ``config.tuning_frequency_per_m``: the squared Laplacian at the
    filter's scale), eps2 to its anisotropy (0 on a sphere's apex, large on a ridge). With ``method="nfft"`` they are
    computed on the back-projected 3-D surface and do not depend on the distance or the camera; ``method="fft"``
    filters the pixel grid as if the object were at ``config.equivalence_range_m``.

    Parameters
    ----------
    range_m : (H, W) float ndarray
        Radial range in metres along each pixel's ray (not z-depth: see `range_from_depth`). NaN, inf and values
        <= 0 are holes: left out, NaN in the result, the rest of the frame unaffected.
    intrinsics : Intrinsics
        The camera's intrinsics in pixels, lens model included; ``(intrinsics.height, intrinsics.width)`` must equal
        ``range_m.shape``.
    mask : (H, W) bool ndarray, optional
        The surface to filter (for example a segmented face). None: every pixel with a finite range > 0.
    method : {"nfft", "fft"}
        "nfft": scale-invariant features of the 3-D surface (points farther than half the patch,
        ``config.patch_width_m`` x ``config.patch_height_m``, from the mask's centroid get NaN); "fft": features of
        the pixel grid read at the equivalence range.
    config : FeatureConfig, optional
        The band, grid and solver settings; default ``FeatureConfig()``.

    Returns
    -------
    Eccentricities
        ``eps0``, ``eps2``: (H, W) float64 ndarrays in square metres, NaN outside the mask and at holes;
        ``iterations`` and ``residual``: the NFFT path's conjugate-gradient iterations and final relative residual.
        It unpacks: ``eps0, eps2 = tofd.eccentricities(...)``.

    Warns
    -----
    PatchWarning
        (NFFT) when points of the mask lie outside the patch: their features are NaN.

    Notes
    -----
    The set-up (FFT plans and filters, NUFFT plans, CG buffers) is made once per camera, config and method and
    kept (`tofd.plan.PLANS_KEPT` of them), so calling this frame after frame costs about what the
    pipeline pays per frame; `tofd.FeaturePlan` holds one explicitly.

    Raises
    ------
    ValueError
        Naming the argument: wrong type, dtype or shape, a range that looks like millimetres, an unknown method, or
        (NFFT) pixels too coarse at the object's range for the band (tofd.algorithm.features.SamplingError).
    """
    return _plan(intrinsics, config, method).eccentricities(range_m, mask=mask)


def surface_filter(range_m: np.ndarray, intrinsics: Intrinsics, transfer: Transfer, *,
                   mask: np.ndarray | None = None, method: Method = "nfft",
                   config: FeatureConfig | None = None) -> np.ndarray:
    """Apply a linear operator, given by its transfer function, to the surface seen in a range image.

    The surface is the depth z(x, y) of the back-projected points (NFFT: x, y in metres on the surface; FFT: the
    pixel grid scaled to metres at ``config.equivalence_range_m``), offset so its maximum is 0. The result is the
    inverse Fourier transform of ``transfer(kx, ky)`` times the surface's spectrum, at each pixel. The NFFT path
    fits the spectrum up to ``config.grid_size / 2`` modes over the patch, with ``config.damping``; outside the
    band of the config's filters the operator is applied to the damped fit.

    Parameters
    ----------
    range_m : (H, W) float ndarray
        Radial range in metres; holes as in `eccentricities`.
    intrinsics : Intrinsics
        The camera's intrinsics in pixels, lens model included.
    transfer : callable
        ``transfer(kx, ky) -> H``: kx, ky are float64 ndarrays of spatial frequencies in cycles per metre (x right,
        y down) of one shape S; H is the operator's transfer values, shape S, or (K, *S) for K operators at once.
        Real or complex; an operator with ``H(-k) == conj(H(k))`` (Hermitian) maps the real surface to a real field.
    mask : (H, W) bool ndarray, optional
        The surface to filter; None: every pixel with a finite range > 0.
    method : {"nfft", "fft"}
        As in `eccentricities`.
    config : FeatureConfig, optional
        Grid, patch and solver settings; default ``FeatureConfig()``.

    Returns
    -------
    (H, W) or (K, H, W) ndarray
        The filtered field(s) in the transfer's units times metres: float64 if every operator is Hermitian, else
        complex128; NaN outside the mask, at holes and (NFFT) outside the patch. (H, W) when `transfer` returns one
        operator.

    Warns
    -----
    PatchWarning
        As in `eccentricities`.
    BandWarning
        (NFFT) when the operator keeps more than `tofd.plan.BAND_WARNING_FRACTION` of its peak magnitude beyond the
        config's band edge, where the fit is damped rather than measured (a Laplacian without a taper).

    Notes
    -----
    The set-up is kept as in `eccentricities`, per operator too for a hashable `transfer` (a function defined
    once, or `eccentricity_transfer`'s result): a lambda made anew for every frame is set up anew every frame.

    Raises
    ------
    ValueError
        As `eccentricities`, and naming `transfer` when it fails or returns values of the wrong shape or non-finite.
        The NFFT path's sampling check uses the config's band (``tuning_frequency_per_m``, ``lowpass_sigma_per_m``)
        and grid: set them to the band your operator needs.
    """
    return _plan(intrinsics, config, method).surface_filter(range_m, transfer, mask=mask)


def eccentricity_transfer(n: int, config: FeatureConfig | None = None) -> Transfer:
    """The transfer function of the order-n eccentricity filters [C_n, S_n] for `surface_filter`.

    C_n(k) = i^n A(rho) cos(n theta), S_n(k) = i^n A(rho) sin(n theta), with A the config's radial tuning and
    (rho, theta) the polar form of k; eps_n = c_n^2 + s_n^2 of the two fields (eps0 and eps2 of `eccentricities`
    for n = 0 and 2).

    Parameters
    ----------
    n : int
        The order, >= 0.
    config : FeatureConfig, optional
        The band (``tuning_frequency_per_m``, ``lowpass_sigma_per_m``); default ``FeatureConfig()``.

    Returns
    -------
    callable
        ``transfer(kx, ky) -> (2, *S)`` complex128 ndarray; equal for equal n and band, so plans reuse its set-up.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    cfg = check_config(config)
    return EccentricityTransfer(int(n), cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)


@dataclass(frozen=True, slots=True)
class EccentricityTransfer:
    """The transfer of [C_n, S_n] for a band (cycles per metre); equal ones share a plan's set-up."""

    n: int
    rho0_per_m: float
    sigma_per_m: float

    def __call__(self, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
        return eccentricity_filters(kx, ky, self.n, self.rho0_per_m, self.sigma_per_m)


def range_from_depth(depth: np.ndarray, intrinsics: Intrinsics, *, scale: float) -> np.ndarray:
    """Radial range (metres along each pixel's ray) from a z-depth image as depth cameras give it.

    Parameters
    ----------
    depth : (H, W) ndarray of integers or floats
        Depth along the optical axis in units of `scale` metres (for example uint16 millimetres with
        ``scale=0.001``). 0, negative and non-finite values are invalid.
    intrinsics : Intrinsics
        The camera's intrinsics; each pixel's ray comes from ``intrinsics.unit_rays()``.
    scale : float
        Metres per depth unit, > 0.

    Returns
    -------
    (H, W) float64 ndarray
        Range in metres, ``depth * scale / ray_z``; NaN where the depth is invalid.
    """
    check_intrinsics(intrinsics)
    depth = checked_image("depth", depth, intrinsics, allow_integers=True)
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating, np.integer)) \
            or not np.isfinite(scale) or not scale > 0:
        raise ValueError(f"scale must be a finite number of metres per depth unit > 0, got {scale!r}")
    z = depth.astype(np.float64) * float(scale)
    with np.errstate(invalid="ignore"):
        z[~(np.isfinite(z) & (z > 0))] = np.nan
    return intrinsics.radial_from_z(z)


def _plan(intrinsics: Intrinsics, config: FeatureConfig | None, method: Method) -> FeaturePlan:
    """The cached plan for these arguments (checked first, so a bad one is named rather than cached)."""
    check_intrinsics(intrinsics)
    cfg = check_config(config)
    check_method(method)
    return cached_plan(intrinsics, cfg, method)
