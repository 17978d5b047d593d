"""FFT path: generalized eccentricities of the range and amplitude images on the pixel grid.

The image (foreground kept, background replaced by a constant) is placed in a buffer with
`fft_padding_px` of background on every side (sizes rounded up to fast FFT lengths), so the filter's
circular convolution does not wrap foreground from one image border onto the other. One rfft2, three
products with the precomputed transfer grids, three irfft2 (scipy.fft, workers=1). The filters are the
physical ones of transfer.py at pixel frequencies times f/e, so these features equal the NFFT features for an
object at range e and change with distance elsewhere (the paper's point).
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from scipy import ndimage

from drivers.intrinsics import Intrinsics
from tofd.algorithm.band import band_edge_per_m
from tofd.algorithm.features.eccentricity import Eccentricities
from tofd.algorithm.features.operators import OperatorGrid, Transfer, eccentricity_transfer, evaluate
from tofd.algorithm.features.transfer import pixel_frequencies_per_m
from tofd.algorithm.params import FeatureConfig


def check_frame(image: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, name: str) -> None:
    """Raise ValueError naming the argument unless image and mask have the camera's shape."""
    if image.shape != intrinsics.shape:
        raise ValueError(f"{name} has shape {image.shape}, expected {intrinsics.shape}")
    if mask.shape != intrinsics.shape or mask.dtype != np.bool_:
        raise ValueError(f"mask must be a bool array of shape {intrinsics.shape}, got {mask.dtype} {mask.shape}")


def usable(values: np.ndarray, mask: np.ndarray, positive: bool) -> np.ndarray:
    """The pixels of `mask` whose value is finite (and > 0 if `positive`): the others are holes, left out."""
    with np.errstate(invalid="ignore"):
        return mask & (np.isfinite(values) & (values > 0) if positive else np.isfinite(values))


def fill_holes(image: np.ndarray, valid: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """`image` with the mask's holes (mask & ~valid) set to their nearest valid pixel's value, so a hole neither
    poisons the FFT with NaN nor puts a step into the surface around it."""
    holes = mask & ~valid
    if not holes.any():
        return image
    nearest = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    filled = image.copy()
    filled[holes] = image[nearest[0][holes], nearest[1][holes]]
    return filled


class FFTFeatures:
    """Precomputed transfer grids and buffer for one camera geometry; call per frame.

    transfer: the operators to apply (tofd.algorithm.features.operators; default the eccentricity filters
    [C0, C2, S2], which range_features and amplitude_features need), read at the equivalence range.
    """

    def __init__(self, intrinsics: Intrinsics, cfg: FeatureConfig, transfer: Transfer | None = None):
        self.intrinsics = intrinsics
        h, w = intrinsics.shape
        edge = band_edge_per_m(cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
        nyquist = min(intrinsics.fx, intrinsics.fy) / (2 * cfg.equivalence_range_m)
        if transfer is None and nyquist < edge:
            raise ValueError(f"intrinsics: the pixel grid at the equivalence range {cfg.equivalence_range_m} m carries "
                             f"up to {nyquist:.1f} cycles/m, short of the filters' band edge {edge:.1f} cycles/m")
        pad = cfg.fft_padding_px
        self._shape = (sfft.next_fast_len(h + 2 * pad, real=True), sfft.next_fast_len(w + 2 * pad, real=True))
        self._window = (slice(pad, pad + h), slice(pad, pad + w))
        self._eccentricity = transfer is None
        operators = self._operators(transfer or eccentricity_transfer(cfg), sfft.rfftfreq(self._shape[1]), cfg)
        self._real, self.stacked = operators.hermitian, operators.stacked
        # (K, rows, cols // 2 + 1) on the real transform's half spectrum if Hermitian, else (K, rows, cols)
        self._transfer = operators.values
        self._buffer = np.empty(self._shape)
        self._rays = intrinsics.unit_rays()
        self._ray_z = self._rays[..., 2]

    def _operators(self, transfer: Transfer, kx: np.ndarray, cfg: FeatureConfig) -> OperatorGrid:
        """The operators on the real transform's half spectrum (kx cycles/pixel), or on the full one unless they are
        Hermitian."""
        ky = sfft.fftfreq(self._shape[0])[:, None]
        operators = evaluate(transfer, *pixel_frequencies_per_m(kx[None, :], ky, self.intrinsics,
                                                                cfg.equivalence_range_m))
        if operators.hermitian or kx.size == self._shape[1]:
            return operators
        return self._operators(transfer, sfft.fftfreq(self._shape[1]), cfg)

    @property
    def operators(self) -> int:
        """K, the number of operators applied."""
        return len(self._transfer)

    def filtered(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
        """(K, H, W) fields of the operators on the depth of a radial range map (see range_features), float64 where
        the operators are Hermitian, else complex128; NaN outside the mask and at its holes."""
        check_frame(range_m, mask, self.intrinsics, "range_m")
        valid = usable(range_m, mask, positive=True)
        if not valid.any():
            dtype = np.float64 if self._real else np.complex128
            return np.full((self.operators, *self.intrinsics.shape), np.nan, dtype)
        depth = fill_holes(range_m, valid, mask) * (self._ray_z if rotation is None else self._rays @ rotation[2])
        return self._fields(depth, mask, valid, float(np.max(depth[valid])), 1.0)

    def range_features(self, range_m: np.ndarray, mask: np.ndarray,
                       rotation: np.ndarray | None = None) -> Eccentricities:
        """eps0, eps2 (metres^2) of a radial range map; background = the maximum foreground depth.

        rotation: camera -> face frame (tofd.algorithm.segmentation.Foreground); depth is then measured along its row 2.

        The filtered image is the depth z = range * (z component of the pixel's unit ray), the quantity
        the NFFT path filters: radial range adds a spurious curvature 1/d (a fronto-parallel wall has
        range d / cos(angle)), so filtering it would not agree with the NFFT path at e. Pixels of the mask
        whose range is NaN, inf or <= 0 are holes: filled from their nearest valid neighbour for the transform,
        NaN in the result.
        """
        return self._eccentricities(self.filtered(range_m, mask, rotation))

    def amplitude_features(self, amplitude: np.ndarray, mask: np.ndarray) -> Eccentricities:
        """eps0, eps2 (dimensionless) of the amplitude image divided by its median foreground value.

        The normalisation removes the overall gain (integration time, 1/r^2 falloff with distance,
        albedo) so a detector trained at one distance sees comparable values at others. Background =
        the minimum foreground amplitude: the border of a face is its darkest part (grazing incidence,
        farthest), so this is the amplitude analogue of the range's maximum and avoids a step at the
        border. Non-finite amplitudes are holes, as in range_features.
        """
        check_frame(amplitude, mask, self.intrinsics, "amplitude")
        valid = usable(amplitude, mask, positive=False)
        if not valid.any():
            return Eccentricities.empty(self.intrinsics.shape)
        values = amplitude[valid]
        scale = float(np.median(values))
        if not scale > 0:
            return Eccentricities.empty(self.intrinsics.shape)
        image = fill_holes(amplitude, valid, mask)
        return self._eccentricities(self._fields(image, mask, valid, float(np.min(values)), 1.0 / scale))

    def _eccentricities(self, fields: np.ndarray) -> Eccentricities:
        if not self._eccentricity:
            raise ValueError("eccentricities need the default operators; this instance applies a user transfer "
                             "(use filtered)")
        c0, c2, s2 = fields
        return Eccentricities((c0 * c0).astype(np.float32), (c2 * c2 + s2 * s2).astype(np.float32))

    def _fields(self, image: np.ndarray, mask: np.ndarray, valid: np.ndarray, background: float,
                gain: float) -> np.ndarray:
        buf = self._buffer
        buf.fill(background)
        np.copyto(buf[self._window], image, where=mask)
        if gain != 1.0:
            buf *= gain
        out = np.empty((self.operators, *self.intrinsics.shape), np.float64 if self._real else np.complex128)
        if self._real:
            spectrum = sfft.rfft2(buf, workers=1)
            for field, t in zip(out, self._transfer, strict=True):
                field[...] = sfft.irfft2(spectrum * t, s=self._shape, workers=1)[self._window]
        else:
            spectrum = sfft.fft2(buf, workers=1)
            for field, t in zip(out, self._transfer, strict=True):
                field[...] = sfft.ifft2(spectrum * t, workers=1)[self._window]
        np.copyto(out, np.nan, where=~valid)
        return out
