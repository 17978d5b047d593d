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

from drivers.intrinsics import Intrinsics
from tofd.algorithm.features.eccentricity import Eccentricities
from tofd.algorithm.features.transfer import pixel_frequencies_per_m, transfer_functions
from tofd.algorithm.params import FeatureConfig


def check_frame(image: np.ndarray, mask: np.ndarray, intrinsics: Intrinsics, name: str) -> None:
    """Raise ValueError naming the argument unless image and mask have the camera's shape."""
    if image.shape != intrinsics.shape:
        raise ValueError(f"{name} has shape {image.shape}, expected {intrinsics.shape}")
    if mask.shape != intrinsics.shape or mask.dtype != np.bool_:
        raise ValueError(f"mask must be a bool array of shape {intrinsics.shape}, got {mask.dtype} {mask.shape}")


class FFTFeatures:
    """Precomputed transfer grids and buffer for one camera geometry; call per frame."""

    def __init__(self, intrinsics: Intrinsics, cfg: FeatureConfig):
        self.intrinsics = intrinsics
        h, w = intrinsics.shape
        pad = cfg.fft_padding_px
        self._shape = (sfft.next_fast_len(h + 2 * pad, real=True), sfft.next_fast_len(w + 2 * pad, real=True))
        self._window = (slice(pad, pad + h), slice(pad, pad + w))
        kx, ky = pixel_frequencies_per_m(sfft.rfftfreq(self._shape[1])[None, :], sfft.fftfreq(self._shape[0])[:, None],
                                         intrinsics, cfg.equivalence_range_m)
        # (3, rows, cols // 2 + 1): C0, C2, S2
        self._transfer = transfer_functions(kx, ky, cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
        self._buffer = np.empty(self._shape)
        self._rays = intrinsics.unit_rays()
        self._ray_z = self._rays[..., 2]

    def range_features(self, range_m: np.ndarray, mask: np.ndarray,
                       rotation: np.ndarray | None = None) -> Eccentricities:
        """eps0, eps2 (metres^2) of a radial range map; background = the maximum foreground depth.

        rotation: camera -> face frame (tofd.algorithm.segmentation.Foreground); depth is then measured along its row 2.

        The filtered image is the depth z = range * (z component of the pixel's unit ray), the quantity
        the NFFT path filters: radial range adds a spurious curvature 1/d (a fronto-parallel wall has
        range d / cos(angle)), which on a sphere of radius 0.1 m at e made FFT eps0 1.5x the NFFT value;
        on depth the two agree at e up to the perspective of the object's own depth.
        """
        check_frame(range_m, mask, self.intrinsics, "range_m")
        if not mask.any():
            return Eccentricities.empty(self.intrinsics.shape)
        depth = range_m * (self._ray_z if rotation is None else self._rays @ rotation[2])
        return self._eccentricities(depth, mask, float(np.max(depth[mask])), 1.0)

    def amplitude_features(self, amplitude: np.ndarray, mask: np.ndarray) -> Eccentricities:
        """eps0, eps2 (dimensionless) of the amplitude image divided by its median foreground value.

        The normalisation removes the overall gain (integration time, 1/r^2 falloff with distance,
        albedo) so a detector trained at one distance sees comparable values at others. Background =
        the minimum foreground amplitude: the border of a face is its darkest part (grazing incidence,
        farthest), so this is the amplitude analogue of the range's maximum and avoids a step at the
        border.
        """
        check_frame(amplitude, mask, self.intrinsics, "amplitude")
        if not mask.any():
            return Eccentricities.empty(self.intrinsics.shape)
        values = amplitude[mask]
        scale = float(np.median(values))
        if not scale > 0:
            return Eccentricities.empty(self.intrinsics.shape)
        return self._eccentricities(amplitude, mask, float(np.min(values)), 1.0 / scale)

    def _eccentricities(self, image: np.ndarray, mask: np.ndarray, background: float, gain: float) -> Eccentricities:
        buf = self._buffer
        buf.fill(background)
        np.copyto(buf[self._window], image, where=mask)
        if gain != 1.0:
            buf *= gain
        spectrum = sfft.rfft2(buf, workers=1)
        c0, c2, s2 = (sfft.irfft2(spectrum * t, s=self._shape, workers=1)[self._window] for t in self._transfer)
        eps0 = np.where(mask, c0 * c0, np.nan).astype(np.float32)
        eps2 = np.where(mask, c2 * c2 + s2 * s2, np.nan).astype(np.float32)
        return Eccentricities(eps0, eps2)
