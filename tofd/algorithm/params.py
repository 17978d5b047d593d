"""Parameters of the algorithm: segmentation, features and detector; each field says its unit."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import Literal, get_args

from tofd.algorithm.band import band_edge_per_m
from tofd.algorithm.names import VARIANTS
from tofd.drivers.intrinsics import Intrinsics

FFTInput = Literal["z", "range"]
FFT_INPUTS: tuple[str, ...] = get_args(FFTInput)
"""What the FFT path filters: z-depth (range times each ray's z component) or the radial range."""

_SR3000 = Intrinsics()
SR3000_PATCH_M = (_SR3000.width / _SR3000.fx * 0.5, _SR3000.height / _SR3000.fy * 0.5)
"""The SR3000's field of view at 0.5 m (width, height), metres: the NFFT patch the shipped model was trained with."""


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    """Foreground segmentation (tofd.algorithm.segmentation): amplitude threshold, then an iso-range cut."""

    amplitude_method: str = "otsu"  # the only method: Otsu's threshold on the finite log amplitudes
    range_percentile: float = 1.0  # percent: reference (robust nearest) range = this percentile of the filtered ranges
    depth_margin_m: float = 0.025  # metres: keep pixels whose filtered range <= reference + this
    median_px: int = 5  # pixels: median filter of the range before the cut (1 = none; 3 or 5)
    morphology_px: int = 3  # pixels: ellipse of the opening + closing of the mask (1 = none)
    nearest_component: bool = True  # keep only the 8-connected region holding the nearest kept pixel
    head_height_m: float = 0.18  # metres: nearest point / component searched this far below the top (0 = anywhere)
    plane_iterations: int = 2  # fits of the face plane the cut is made along (0 = cut along the camera's z axis)
    plane_depth_m: float = 0.04  # metres: the face front the plane is fitted to, behind the nearest point
    plane_max_tilt_deg: float = 45.0  # degrees: largest tilt of the face frame from the camera's z axis

    def validate(self) -> None:
        if self.amplitude_method != "otsu":
            raise ValueError(f"amplitude_method: {self.amplitude_method!r} is not one of 'otsu'")
        if not 0.0 <= self.range_percentile <= 100.0:
            raise ValueError(f"range_percentile: {self.range_percentile} is not in [0, 100]")
        if not self.depth_margin_m > 0:
            raise ValueError(f"depth_margin_m: {self.depth_margin_m} must be > 0")
        if self.median_px not in (1, 3, 5):
            raise ValueError(f"median_px: {self.median_px} is not one of 1, 3, 5")
        if self.morphology_px < 1:
            raise ValueError(f"morphology_px: {self.morphology_px} must be >= 1")
        if not self.head_height_m >= 0:
            raise ValueError(f"head_height_m: {self.head_height_m} must be >= 0 (0 = no head band)")
        if self.plane_iterations < 0:
            raise ValueError(f"plane_iterations: {self.plane_iterations} must be >= 0 (0 = camera z axis)")
        if not self.plane_depth_m > 0:
            raise ValueError(f"plane_depth_m: {self.plane_depth_m} must be > 0")
        if not 0.0 <= self.plane_max_tilt_deg < 90.0:
            raise ValueError(f"plane_max_tilt_deg: {self.plane_max_tilt_deg} is not in [0, 90)")


_FLOAT_FIELDS = ("equivalence_range_m", "tuning_frequency_per_m", "lowpass_sigma_per_m", "damping", "cg_tolerance",
                 "nufft_eps", "patch_width_m", "patch_height_m")  # FeatureConfig's numbers > 0
_INT_FIELDS = ("grid_size", "fft_padding_px", "cg_max_iterations")  # FeatureConfig's integers


@dataclass(frozen=True, slots=True)
class FeatureConfig:
    """Generalized-eccentricity features (FFT and NFFT paths, tofd.algorithm.features); frequencies in cycles/metre.

    The NFFT path is set in metres only: a patch_width_m x patch_height_m patch centred on the foreground carries a
    grid_size x grid_size grid of modes k / patch (cycles per metre), so its features do not depend on the camera.
    Validated when constructed (ValueError naming the field); numpy scalars are taken as the Python numbers they equal
    (an integer field refuses a float such as 64.0).
    """

    equivalence_range_m: float = 0.5  # e: FFT path: the pixel grid is read at this range (cycles/pixel * f / e)
    tuning_frequency_per_m: float = 30.0  # rho0: peak of the radial tuning A(rho), cycles/m
    lowpass_sigma_per_m: float = 50.0  # Gaussian low-pass width, cycles/m (anti-aliasing for the NFFT grid)
    fft_padding_px: int = 16  # FFT path: least background margin per side against wrap-around, pixels (more where
    # the filters reach farther in pixels: tofd.algorithm.features.fft)
    grid_size: int = 64  # NFFT path: N, frequency grid N x N (even); must reach the band edge over the patch
    patch_width_m: float = SR3000_PATCH_M[0]  # NFFT path: patch width (x), metres; mode k is k / width cycles/m
    patch_height_m: float = SR3000_PATCH_M[1]  # NFFT path: patch height (y), metres
    damping: float = 0.01  # NFFT path: relative shrinkage; lambda = damping * points per patch area (see nfft.py)
    cg_tolerance: float = 7e-5  # NFFT path: stop CG at this relative band-weighted residual
    cg_max_iterations: int = 100  # NFFT path: CG iteration cap
    nufft_eps: float = 1e-4  # NFFT path: finufft requested relative precision
    cg_precision: Literal["single", "double"] = "single"  # NFFT path: float width of NUFFTs and CG
    fft_input: FFTInput = "z"  # FFT path: filter the z-depth (range times the ray's z, the NFFT path's surface) or
    # the radial "range" itself (the paper's baseline)

    def __post_init__(self) -> None:
        for key in _FLOAT_FIELDS + _INT_FIELDS:  # numpy scalars as Python numbers: equal configs hash alike
            value = getattr(self, key)
            if isinstance(value, bool):
                continue
            if key in _INT_FIELDS and isinstance(value, numbers.Integral):
                object.__setattr__(self, key, int(value))
            elif key in _FLOAT_FIELDS and isinstance(value, numbers.Real):
                object.__setattr__(self, key, float(value))
        self.validate()

    @property
    def band_edge_per_m(self) -> float:
        """Cycles per metre above which the filters' radial tuning is below tofd.algorithm.band.BAND_FLOOR of its
        peak."""
        return band_edge_per_m(self.tuning_frequency_per_m, self.lowpass_sigma_per_m)

    @property
    def grid_nyquist_per_m(self) -> tuple[float, float]:
        """(x, y) highest frequency of the NFFT grid, N / 2 / patch side, cycles per metre."""
        return self.grid_size / 2 / self.patch_width_m, self.grid_size / 2 / self.patch_height_m

    def validate(self) -> None:
        for key in _FLOAT_FIELDS:
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or value == math.inf:
                raise ValueError(f"{key}: {value!r} must be a finite number > 0")
        for key in _INT_FIELDS:
            if isinstance(getattr(self, key), bool) or not isinstance(getattr(self, key), int):
                raise ValueError(f"{key}: {getattr(self, key)!r} must be an integer")
        if self.grid_size < 8 or self.grid_size % 2:
            raise ValueError(f"grid_size: {self.grid_size} must be even and >= 8")
        if self.fft_padding_px < 0:
            raise ValueError(f"fft_padding_px: {self.fft_padding_px} must be >= 0")
        if self.cg_max_iterations < 1:
            raise ValueError(f"cg_max_iterations: {self.cg_max_iterations} must be >= 1")
        if not 1e-14 <= self.nufft_eps < 1e-1:
            raise ValueError(f"nufft_eps: {self.nufft_eps} is not in [1e-14, 0.1)")
        if self.fft_input not in FFT_INPUTS:
            raise ValueError(f"fft_input: {self.fft_input!r} is not one of {', '.join(map(repr, FFT_INPUTS))}")
        if self.cg_precision not in ("single", "double"):
            raise ValueError(f"cg_precision: {self.cg_precision!r} is not one of 'single', 'double'")
        edge, reach = self.band_edge_per_m, min(self.grid_nyquist_per_m)
        if reach < edge:
            raise ValueError(f"grid_size: {self.grid_size} modes over a {self.patch_width_m:.3g} x "
                             f"{self.patch_height_m:.3g} m patch reach {reach:.1f} cycles/m, short of the filters' "
                             f"band edge {edge:.1f} cycles/m (raise grid_size to at least "
                             f"{least_grid_size(edge, self.patch_width_m, self.patch_height_m)})")

    def tuned_to(self, tuning_frequency_per_m: float) -> FeatureConfig:
        """This config with the filters tuned to `tuning_frequency_per_m` (cycles/m), its grid_size raised to the
        least that reaches the new band edge where it falls short."""
        edge = band_edge_per_m(tuning_frequency_per_m, self.lowpass_sigma_per_m)
        return replace(self, tuning_frequency_per_m=tuning_frequency_per_m,
                       grid_size=max(self.grid_size, least_grid_size(edge, self.patch_width_m, self.patch_height_m)))


def least_grid_size(band_edge_per_m: float, patch_width_m: float, patch_height_m: float) -> int:
    """The least even NFFT grid size whose Nyquist frequency over a patch of these sides (m) reaches the band edge
    (cycles/m)."""
    return 2 * math.ceil(band_edge_per_m * max(patch_width_m, patch_height_m))


def recorded_feature_settings(recorded: dict) -> dict:
    """Feature settings recorded with a model (dataclasses.asdict(FeatureConfig) at training time) in today's keys.

    Settings without the patch keys (model files written before they existed) used the camera's field of view at the
    equivalence range as the NFFT patch; those models were trained on the SR3000, so it is the SR3000's. Settings
    without fft_input filtered z-depth.
    """
    recorded = {"fft_input": "z", **recorded}
    if "patch_width_m" in recorded or "patch_height_m" in recorded:
        return dict(recorded)
    e = recorded.get("equivalence_range_m", FeatureConfig().equivalence_range_m)
    if not isinstance(e, (int, float)):
        return dict(recorded)  # the comparison names the bad value
    return {**recorded, "patch_width_m": _SR3000.width / _SR3000.fx * e,
            "patch_height_m": _SR3000.height / _SR3000.fy * e}


@dataclass(frozen=True, slots=True)
class DetectorConfig:
    """Nose detector (tofd.algorithm.detector): the model file, which of its variants to use, and the box scale."""

    model_path: str = "nose_model.json"  # JSON model; relative: from the config file's directory (never the cwd)
    variant: str = "nfft_range"  # fft_range, fft_range_amp, nfft_range or nfft_range_amp
    box_scale: float = 0.0  # box half-widths times this (> 0); 0 = the model's operating scale (training EER)
    border_margin_m: float = 0.006  # metres: pixels nearer than this to the mask border are never the nose
    front_depth_m: float = 0.001  # metres: pixels this far behind the front-most one within 12 mm are never the
    # nose (0 = no front test; tofd/algorithm/detector/candidates.py)
    front_noise_factor: float = 0.0  # the front test allows front_depth_m + this x the pixel's local range noise
    # sigma (estimated from the frame; tofd/algorithm/detector/candidates.py); 0 = fixed allowance
    margin_ratio: float = 0.7  # the best pixel is reported only if its box distance is at most this times that of
    # the best pixel 2 cm or more away from it (tofd/algorithm/detector/acceptance.py); 0 = no margin test
    margin_scale_factor: float = 2.0  # with the margin test on, the box scale is the operating scale times this
    tip_radius_m: float = 0.016  # metres: window radius of the sub-pixel tip fit about the accepted pixel
    # (tofd/algorithm/detector/tip.py); 0 = report the accepted pixel itself

    def validate(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant: {self.variant!r} is not one of {', '.join(VARIANTS)}")
        if not self.box_scale >= 0:
            raise ValueError(f"box_scale: {self.box_scale} must be >= 0 (0 = the model's operating scale)")
        if not self.border_margin_m >= 0:
            raise ValueError(f"border_margin_m: {self.border_margin_m} must be >= 0 (0 = no exclusion)")
        if not self.front_depth_m >= 0:
            raise ValueError(f"front_depth_m: {self.front_depth_m} must be >= 0 (0 = no front test)")
        if not self.front_noise_factor >= 0:
            raise ValueError(f"front_noise_factor: {self.front_noise_factor} must be >= 0 (0 = fixed allowance)")
        if not 0 <= self.margin_ratio < 1:
            raise ValueError(f"margin_ratio: {self.margin_ratio} is not in [0, 1) (0 = no margin test)")
        if not self.tip_radius_m >= 0:
            raise ValueError(f"tip_radius_m: {self.tip_radius_m} must be >= 0 (0 = no tip fit)")
        if not self.margin_scale_factor >= 1:
            raise ValueError(f"margin_scale_factor: {self.margin_scale_factor} must be >= 1")
