"""The FFT path transforms the foreground's bounding box plus the filters' reach: its fields at the mask equal a
whole-frame computation with a wide padding (written out here from the transfer functions) on every camera."""

import numpy as np
import pytest
import scipy.fft as sfft

from tofd.algorithm.features import FFTFeatures
from tofd.algorithm.features.transfer import pixel_frequencies_per_m, transfer_functions
from tofd.config import FeatureConfig
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics

CFG = FeatureConfig()
CAMERAS = {"sr3000": Intrinsics(), "640x576": Intrinsics(640, 576, 504.0, 504.0, 319.5, 287.5)}
WIDE_PAD = 200  # pixels of background around the whole frame: the filters' response is gone long before


def whole_frame_fields(intr: Intrinsics, image: np.ndarray, mask: np.ndarray, background: float,
                       gain: float = 1.0) -> np.ndarray:
    """(3, H, W) fields [c0, c2, s2] of the whole frame (mask pixels kept, the rest `background`) times `gain`."""
    h, w = intr.shape
    shape = (h + 2 * WIDE_PAD, w + 2 * WIDE_PAD)
    buf = np.full(shape, background, np.float64)
    window = (slice(WIDE_PAD, WIDE_PAD + h), slice(WIDE_PAD, WIDE_PAD + w))
    buf[window][mask] = image[mask]
    buf *= gain
    kx, ky = pixel_frequencies_per_m(sfft.rfftfreq(shape[1])[None, :], sfft.fftfreq(shape[0])[:, None], intr,
                                     CFG.equivalence_range_m)
    t = transfer_functions(kx, ky, CFG.tuning_frequency_per_m, CFG.lowpass_sigma_per_m)
    return sfft.irfft2(sfft.rfft2(buf)[None] * t, s=shape)[(slice(None), *window)]


def face(intr: Intrinsics, distance_m: float, shift_px: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rendered face's range, amplitude and foreground mask (shifted right by `shift_px` columns)."""
    r = render_face(load_face("lee_perry_smith"), Pose(distance_m=distance_m, yaw_deg=15.0, pitch_deg=5.0), intr,
                    np.random.default_rng(3))
    mask = np.isfinite(r.range_m) & (r.range_m < np.nanmin(r.range_m) + 0.08)
    return (np.roll(r.range_m, shift_px, axis=1), np.roll(r.amplitude, shift_px, axis=1),
            np.roll(mask, shift_px, axis=1))


@pytest.mark.parametrize("camera", list(CAMERAS))
@pytest.mark.parametrize("distance_m", [0.35, 0.6])
def test_box_fields_equal_the_whole_frame(camera, distance_m):
    intr = CAMERAS[camera]
    fft = FFTFeatures(intr, CFG)
    range_m, amplitude, mask = face(intr, distance_m)
    depth = range_m * intr.unit_rays()[..., 2]
    ref = whole_frame_fields(intr, depth, mask, float(np.max(depth[mask])))
    got = fft.filtered(range_m, mask)
    scale = np.max(np.abs(ref[:, mask]))
    np.testing.assert_allclose(got[:, mask], ref[:, mask], rtol=0, atol=1e-8 * scale)
    assert np.all(np.isnan(got[:, ~mask]))
    # the eccentricities are the squares of those fields, in float32
    maps = fft.range_features(range_m, mask)
    np.testing.assert_allclose(maps.eps0[mask], ref[0, mask] ** 2, rtol=1e-5, atol=1e-7 * scale**2)
    np.testing.assert_allclose(maps.eps2[mask], ref[1, mask] ** 2 + ref[2, mask] ** 2, rtol=1e-5,
                               atol=1e-7 * scale**2)
    # amplitude: over its median, background the minimum
    amp = fft.amplitude_features(amplitude, mask)
    values = amplitude[mask]
    ref_amp = whole_frame_fields(intr, amplitude, mask, float(values.min()), 1.0 / float(np.median(values)))
    amp_scale = np.max(ref_amp[0, mask] ** 2)
    np.testing.assert_allclose(amp.eps0[mask], ref_amp[0, mask] ** 2, rtol=1e-5, atol=1e-7 * amp_scale)


def test_box_at_the_frame_border_equals_the_whole_frame():
    """A face cut by the right border: the box reaches the frame's edge and is still padded like the frame."""
    intr = CAMERAS["640x576"]
    range_m, _, mask = face(intr, 0.5, shift_px=300)
    assert mask[:, -1].any()
    depth = range_m * intr.unit_rays()[..., 2]
    ref = whole_frame_fields(intr, depth, mask, float(np.max(depth[mask])))
    got = FFTFeatures(intr, CFG).filtered(range_m, mask)
    np.testing.assert_allclose(got[:, mask], ref[:, mask], rtol=0, atol=1e-8 * np.max(np.abs(ref[:, mask])))


def test_padding_follows_the_filters_reach_in_pixels():
    """Finer pixels make the same filter wider in pixels: the padding grows beyond fft_padding_px; never below it."""
    sr3000, fine = FFTFeatures(CAMERAS["sr3000"], CFG), FFTFeatures(CAMERAS["640x576"], CFG)
    assert sr3000.padding_px == (CFG.fft_padding_px, CFG.fft_padding_px)
    assert min(fine.padding_px) > CFG.fft_padding_px
    wide = FFTFeatures(CAMERAS["sr3000"], FeatureConfig(fft_padding_px=40))
    assert wide.padding_px == (40, 40)


def test_non_local_operator_transforms_the_whole_frame():
    """An operator whose response never fades (1 / |k|, a fractional integral) is not cut to the box: the fields
    equal the whole frame padded by fft_padding_px."""
    intr = CAMERAS["sr3000"]

    def integral(kx, ky):
        rho = np.hypot(kx, ky)
        return np.where(rho > 0, 1.0 / np.where(rho > 0, rho, 1.0), 0.0)

    fft = FFTFeatures(intr, CFG, transfer=integral)
    range_m, _, mask = face(intr, 0.5)
    assert fft.box(mask) == (slice(0, intr.height), slice(0, intr.width))
    depth = range_m * intr.unit_rays()[..., 2]
    pad = CFG.fft_padding_px
    shape = (sfft.next_fast_len(intr.height + 2 * pad, real=True), sfft.next_fast_len(intr.width + 2 * pad, real=True))
    buf = np.full(shape, float(np.max(depth[mask])))
    buf[pad:pad + intr.height, pad:pad + intr.width][mask] = depth[mask]
    kx, ky = pixel_frequencies_per_m(sfft.rfftfreq(shape[1])[None, :], sfft.fftfreq(shape[0])[:, None], intr,
                                     CFG.equivalence_range_m)
    ref = sfft.irfft2(sfft.rfft2(buf) * integral(kx, ky), s=shape)[pad:pad + intr.height, pad:pad + intr.width]
    got = fft.filtered(range_m, mask)[0]
    np.testing.assert_allclose(got[mask], ref[mask], rtol=1e-10, atol=1e-12 * np.max(np.abs(ref[mask])))
