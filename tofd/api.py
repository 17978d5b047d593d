"""The public functions on the user's own arrays: eccentricities, any surface operator, range from depth.

Array in, array out, in the style of scikit-image: every function checks its inputs here (one ValueError naming
the argument) and runs the same feature code as the pipeline (tofd.algorithm.features). Units: metres for range,
cycles per metre for spatial frequencies, pixels for intrinsics.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from tofd.algorithm.features import Eccentricities, FFTFeatures, NFFTFeatures, Transfer
from tofd.algorithm.features.transfer import eccentricity_filters
from tofd.algorithm.params import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics

Method = Literal["nfft", "fft"]
METHODS: tuple[str, ...] = ("nfft", "fft")
MAX_PLAUSIBLE_RANGE_M = 20.0
"""A median range beyond this (metres) is taken for millimetres: time-of-flight cameras see a few metres."""


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
        The camera's pinhole intrinsics in pixels; ``(intrinsics.height, intrinsics.width)`` must equal
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
        ``eps0``, ``eps2``: (H, W) float32 ndarrays in square metres, NaN outside the mask and at holes;
        ``iterations`` and ``residual``: the NFFT path's conjugate-gradient iterations and final relative residual.

    Raises
    ------
    ValueError
        Naming the argument: wrong type, dtype or shape, a range that looks like millimetres, an unknown method, or
        (NFFT) pixels too coarse at the object's range for the band (tofd.algorithm.features.SamplingError).
    """
    cfg, mask = _checked(range_m, intrinsics, mask, method, config)
    if method == "fft":
        return FFTFeatures(intrinsics, cfg).range_features(range_m, mask)
    return NFFTFeatures(intrinsics, cfg).range_features(range_m, mask)


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
        The camera's pinhole intrinsics in pixels.
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

    Raises
    ------
    ValueError
        As `eccentricities`, and naming `transfer` when it fails or returns values of the wrong shape or non-finite.
        The NFFT path's sampling check uses the config's band (``tuning_frequency_per_m``, ``lowpass_sigma_per_m``)
        and grid: set them to the band your operator needs.
    """
    cfg, mask = _checked(range_m, intrinsics, mask, method, config)
    if not callable(transfer):
        raise ValueError(f"transfer must be a callable transfer(kx, ky), got {type(transfer).__name__}")
    features = (FFTFeatures if method == "fft" else NFFTFeatures)(intrinsics, cfg, transfer)
    fields = features.filtered(range_m, mask)
    return fields if features.stacked else fields[0]


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
        ``transfer(kx, ky) -> (2, *S)`` complex128 ndarray.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    cfg = _config(config)
    rho0, sigma = cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m
    return lambda kx, ky: eccentricity_filters(kx, ky, int(n), rho0, sigma)


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
    _check_intrinsics(intrinsics)
    depth = checked_image("depth", depth, intrinsics, allow_integers=True)
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating, np.integer)) \
            or not np.isfinite(scale) or not scale > 0:
        raise ValueError(f"scale must be a finite number of metres per depth unit > 0, got {scale!r}")
    z = depth.astype(np.float64) * float(scale)
    with np.errstate(invalid="ignore"):
        z[~(np.isfinite(z) & (z > 0))] = np.nan
    return z / intrinsics.unit_rays()[..., 2]


def _config(config: FeatureConfig | None) -> FeatureConfig:
    if config is None:
        return FeatureConfig()
    if not isinstance(config, FeatureConfig):
        raise ValueError(f"config must be a tofd.FeatureConfig, got {type(config).__name__}")
    return config


def _check_intrinsics(intrinsics: Intrinsics) -> None:
    if not isinstance(intrinsics, Intrinsics):
        raise ValueError(f"intrinsics must be a tofd.Intrinsics, got {type(intrinsics).__name__}")


def checked_image(name: str, image: np.ndarray, intrinsics: Intrinsics, allow_integers: bool = False) -> np.ndarray:
    """`image` as an ndarray of the camera's shape and a real number dtype; ValueError naming `name` otherwise."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(image).__name__}")
    kinds = "fiu" if allow_integers else "f"
    if image.dtype.kind not in kinds:
        hint = (" (integer depth in millimetres? use tofd.range_from_depth(depth, intrinsics, scale=0.001))"
                if image.dtype.kind in "iu" else "")
        raise ValueError(f"{name} must be a {'real number' if allow_integers else 'floating-point'} array, "
                         f"got dtype {image.dtype}{hint}")
    if image.shape != intrinsics.shape:
        raise ValueError(f"{name} has shape {image.shape}, expected {intrinsics.shape} (intrinsics height, width)")
    return image


def checked_range(range_m: np.ndarray, intrinsics: Intrinsics, mask: np.ndarray | None) -> np.ndarray:
    """The mask to use (None: every valid pixel) after checking range_m, intrinsics and mask; ValueError naming the
    argument, including for a range that looks like millimetres."""
    _check_intrinsics(intrinsics)
    checked_image("range_m", range_m, intrinsics)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(range_m) & (range_m > 0)
    if mask is None:
        mask = valid
    elif not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != intrinsics.shape:
        got = f"{mask.dtype} {mask.shape}" if isinstance(mask, np.ndarray) else type(mask).__name__
        raise ValueError(f"mask must be a bool array of shape {intrinsics.shape}, got {got}")
    values = range_m[mask & valid]
    if values.size and (median := float(np.median(values))) > MAX_PLAUSIBLE_RANGE_M:
        raise ValueError(f"range_m looks like millimetres, not metres (median {median:g} over the mask); divide by "
                         "1000, or convert depth with tofd.range_from_depth(depth, intrinsics, scale=0.001)")
    return mask


def _checked(range_m: np.ndarray, intrinsics: Intrinsics, mask: np.ndarray | None, method: str,
             config: FeatureConfig | None) -> tuple[FeatureConfig, np.ndarray]:
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    cfg = _config(config)
    return cfg, checked_range(range_m, intrinsics, mask)
