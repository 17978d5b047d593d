"""FFT path: generalized eccentricities of the range and amplitude images on the pixel grid.

The features are only needed on the foreground, and outside it the image is a constant (the background), which
filters of zero response at k = 0 map to 0. So the transform covers the foreground's bounding box plus a padding
of background on every side, as wide as the filters' impulse response reaches (`padding_px`: at least
FeatureConfig.fft_padding_px), so the circular convolution does not wrap the foreground onto itself: the fields
at the foreground equal those of the whole padded frame to within the response's tail (KERNEL_TAIL), at a cost
that follows the object, not the camera's pixel count. Box sizes are rounded up to fast FFT lengths that are
multiples of 8 (few distinct shapes, so each worker keeps a handful of transfer grids, buffers and scipy's
plans). One rfft2, three products with the transfer grids, three irfft2 (scipy.fft, workers=1; three single
inverse transforms are faster here than one batched call). The filters are the physical ones of transfer.py at
pixel frequencies times f/e, so these features equal the NFFT features for an object at range e and change with
distance elsewhere (the paper's point).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import scipy.fft as sfft
from scipy import ndimage

from tofd.algorithm.band import band_edge_per_m
from tofd.algorithm.features.eccentricity import Eccentricities, MapsOut
from tofd.algorithm.features.operators import Transfer, eccentricity_transfer, evaluate
from tofd.algorithm.features.transfer import pixel_frequencies_per_m
from tofd.algorithm.params import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics

KERNEL_TAIL = 1e-9  # fraction of each operator's impulse-response L1 mass allowed beyond the padding
SIZE_STEP = 8  # box FFT lengths are fast lengths that are multiples of this (or the whole frame's)
GRIDS_KEPT = 16  # transfer grids (with their buffers) kept per instance, most recently used


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


def impulse_reach_px(values: np.ndarray, hermitian: bool, shape: tuple[int, int]) -> tuple[int, int] | None:
    """(rows, columns): the distance in pixels from which on every operator's impulse response (transfer `values`
    (K, ...) on the FFT grid of `shape`) holds at most KERNEL_TAIL of its L1 mass; None if one never falls that
    low within the grid (a non-local operator: the whole frame is then transformed)."""
    kernels = np.abs(sfft.irfft2(values, s=shape, workers=1) if hermitian else sfft.ifft2(values, workers=1))
    reach = []
    for axis in (1, 2):
        profile = kernels.sum(axis=3 - axis)  # (K, n): mass per offset along this axis
        n = profile.shape[1]
        distance = np.minimum(np.arange(n), n - np.arange(n))
        by_distance = np.stack([np.bincount(distance, weights=p) for p in profile])
        tail = np.cumsum(by_distance[:, ::-1], axis=1)[:, ::-1]  # mass at distance >= d
        within = np.flatnonzero(np.all(tail <= KERNEL_TAIL * tail[:, :1], axis=0))
        if not within.size:
            return None
        reach.append(int(within[0]))
    return reach[0], reach[1]


def fast_length(needed: int, whole: int) -> int:
    """The FFT length for `needed` samples: the next fast real length that is a multiple of SIZE_STEP, or `whole`
    (the whole padded frame's) if that is not longer."""
    n = needed
    while n < whole:
        n = sfft.next_fast_len(n, real=True)
        if n % SIZE_STEP == 0:
            return min(n, whole)
        n += 1
    return whole


class FFTFeatures:
    """Transfer grids and buffers for one camera geometry (per box shape, made on first use); call per frame.

    transfer: the operators to apply (tofd.algorithm.features.operators; default the eccentricity filters
    [C0, C2, S2], which range_features and amplitude_features need), read at the equivalence range.
    """

    def __init__(self, intrinsics: Intrinsics, cfg: FeatureConfig, transfer: Transfer | None = None):
        self.intrinsics, self._cfg = intrinsics, cfg
        h, w = intrinsics.shape
        edge = band_edge_per_m(cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
        nyquist = min(intrinsics.fx, intrinsics.fy) / (2 * cfg.equivalence_range_m)
        if transfer is None and nyquist < edge:
            raise ValueError(f"intrinsics: the pixel grid at the equivalence range {cfg.equivalence_range_m} m carries "
                             f"up to {nyquist:.1f} cycles/m, short of the filters' band edge {edge:.1f} cycles/m")
        self._eccentricity = transfer is None
        self._transfer_of = transfer or eccentricity_transfer(cfg)
        pad = cfg.fft_padding_px
        probe = (sfft.next_fast_len(h + 2 * pad, real=True), sfft.next_fast_len(w + 2 * pad, real=True))
        operators = evaluate(self._transfer_of, *self._frequencies(probe, full=True))
        self._real, self.stacked = operators.hermitian, operators.stacked
        self.operators = len(operators)  # K, the number of operators applied
        reach = impulse_reach_px(operators.values, operators.hermitian, probe)
        self._crop = reach is not None
        # per side: the padding's own minimum, or half the reach (a wrapped copy of the box lies 2 paddings away)
        self.padding_px = (pad, pad) if reach is None else (max(pad, (reach[0] + 1) // 2),
                                                             max(pad, (reach[1] + 1) // 2))
        self._whole = (sfft.next_fast_len(h + 2 * self.padding_px[0], real=True),
                       sfft.next_fast_len(w + 2 * self.padding_px[1], real=True))
        self._grids: OrderedDict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._rays = intrinsics.unit_rays()

    def _frequencies(self, shape: tuple[int, int], full: bool) -> tuple[np.ndarray, np.ndarray]:
        """(kx, ky) in cycles per metre at the equivalence range on the FFT grid of `shape`: the real transform's
        half spectrum unless `full`."""
        kx = sfft.fftfreq(shape[1]) if full else sfft.rfftfreq(shape[1])
        return pixel_frequencies_per_m(kx[None, :], sfft.fftfreq(shape[0])[:, None], self.intrinsics,
                                       self._cfg.equivalence_range_m)

    def _grid(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """The operators' values on the FFT grid of `shape` ((K, rows, cols // 2 + 1) on the half spectrum if
        Hermitian, else (K, rows, cols)) and a buffer of that shape; the GRIDS_KEPT most recently used are kept."""
        if shape in self._grids:
            self._grids.move_to_end(shape)
        else:
            values = evaluate(self._transfer_of, *self._frequencies(shape, full=not self._real)).values
            self._grids[shape] = (values, np.empty(shape))
            if len(self._grids) > GRIDS_KEPT:
                self._grids.popitem(last=False)
        return self._grids[shape]

    def box(self, mask: np.ndarray) -> tuple[slice, slice]:
        """The rows and columns the transform covers: the mask's bounding box (the whole frame for a non-local
        operator)."""
        if not self._crop:
            return slice(0, mask.shape[0]), slice(0, mask.shape[1])
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)

    def filtered(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None) -> np.ndarray:
        """(K, H, W) fields of the operators on the depth of a radial range map (see range_features), float64 where
        the operators are Hermitian, else complex128; NaN outside the mask and at its holes."""
        out = np.full((self.operators, *self.intrinsics.shape), np.nan, np.float64 if self._real else np.complex128)
        fields = self._range_fields(range_m, mask, rotation)
        if fields is not None:
            out[(slice(None), *fields[0])] = fields[1]
        return out

    def _range_fields(self, range_m: np.ndarray, mask: np.ndarray,
                      rotation: np.ndarray | None) -> tuple[tuple[slice, slice], np.ndarray] | None:
        """The box and the (K, box rows, box columns) fields on the depth in it; None without a valid pixel."""
        check_frame(range_m, mask, self.intrinsics, "range_m")
        if not mask.any():
            return None
        box = self.box(mask)
        mask_box = mask[box]
        range_box = range_m[box]
        valid = usable(range_box, mask_box, positive=True)
        if not valid.any():
            return None
        depth = fill_holes(range_box, valid, mask_box)
        if self._cfg.fft_input == "z":
            rays = self._rays[box]
            depth = depth * (rays[..., 2] if rotation is None else rays @ rotation[2])
        return box, self._fields(depth, mask_box, valid, float(np.max(depth[valid])), 1.0)

    def range_features(self, range_m: np.ndarray, mask: np.ndarray, rotation: np.ndarray | None = None,
                       out: MapsOut | None = None) -> Eccentricities:
        """eps0, eps2 (metres^2) of a radial range map; background = the maximum foreground depth.

        rotation: camera -> face frame (tofd.algorithm.segmentation.Foreground); depth is then measured along its row 2.
        out: two (H, W) float32 arrays the maps are written into (and returned as), e.g. a worker's shared memory.

        The filtered image is, with FeatureConfig.fft_input "z", the depth z = range * (z component of the
        pixel's unit ray), the quantity the NFFT path filters: radial range adds a spurious curvature 1/d (a
        fronto-parallel wall has range d / cos(angle)), so filtering it would not agree with the NFFT path at e;
        with "range", the radial range itself, as the paper's baseline (rotation is then not used). Pixels of the
        mask whose range is NaN, inf or <= 0 are holes: filled from their nearest valid neighbour for the
        transform, NaN in the result.
        """
        return self._eccentricities(self._range_fields(range_m, mask, rotation), out)

    def amplitude_features(self, amplitude: np.ndarray, mask: np.ndarray, out: MapsOut | None = None) -> Eccentricities:
        """eps0, eps2 (dimensionless) of the amplitude image divided by its median foreground value.

        The normalisation removes the overall gain (integration time, 1/r^2 falloff with distance,
        albedo) so a detector trained at one distance sees comparable values at others. Background =
        the minimum foreground amplitude: the border of a face is its darkest part (grazing incidence,
        farthest), so this is the amplitude analogue of the range's maximum and avoids a step at the
        border. Non-finite amplitudes are holes, as in range_features; out: as in range_features.
        """
        check_frame(amplitude, mask, self.intrinsics, "amplitude")
        if not mask.any():
            return self._eccentricities(None, out)
        box = self.box(mask)
        mask_box, amplitude_box = mask[box], amplitude[box]
        valid = usable(amplitude_box, mask_box, positive=False)
        values = amplitude_box[valid]
        scale = float(np.median(values)) if values.size else 0.0
        if not scale > 0:
            return self._eccentricities(None, out)
        image = fill_holes(amplitude_box, valid, mask_box)
        return self._eccentricities((box, self._fields(image, mask_box, valid, float(np.min(values)), 1.0 / scale)),
                                    out)

    def _eccentricities(self, fields: tuple[tuple[slice, slice], np.ndarray] | None,
                        out: MapsOut | None) -> Eccentricities:
        """Full-frame eps0, eps2 maps (in `out` if given) from a box's fields [c0, c2, s2] (None: all NaN)."""
        if not self._eccentricity:
            raise ValueError("eccentricities need the default operators; this instance applies a user transfer "
                             "(use filtered)")
        maps = Eccentricities.empty(self.intrinsics.shape, out=out)
        if fields is not None:
            box, (c0, c2, s2) = fields
            maps.eps0[box] = c0 * c0
            np.multiply(c2, c2, out=c2)
            c2 += s2 * s2
            maps.eps2[box] = c2
        return maps

    def _fields(self, image: np.ndarray, mask: np.ndarray, valid: np.ndarray, background: float,
                gain: float) -> np.ndarray:
        """(K, rows, cols) fields of a box's image (its mask pixels kept, the rest `background`), times `gain`;
        NaN where not `valid`."""
        (pad_y, pad_x), (rows, cols) = self.padding_px, image.shape
        shape = (fast_length(rows + 2 * pad_y, self._whole[0]), fast_length(cols + 2 * pad_x, self._whole[1]))
        transfer, buf = self._grid(shape)
        window = (slice(pad_y, pad_y + rows), slice(pad_x, pad_x + cols))
        buf.fill(background)
        np.copyto(buf[window], image, where=mask)
        if gain != 1.0:
            buf *= gain
        out = np.empty((self.operators, rows, cols), np.float64 if self._real else np.complex128)
        if self._real:
            spectrum = sfft.rfft2(buf, workers=1)
            for field, t in zip(out, transfer, strict=True):
                field[...] = sfft.irfft2(spectrum * t, s=shape, workers=1)[window]
        else:
            spectrum = sfft.fft2(buf, workers=1)
            for field, t in zip(out, transfer, strict=True):
                field[...] = sfft.ifft2(spectrum * t, workers=1)[window]
        np.copyto(out, np.nan, where=~valid)
        return out
