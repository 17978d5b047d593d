import numpy as np
import pytest

from tofd.algorithm.features import Eccentricities, FFTFeatures
from tofd.config import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic

INTR = Intrinsics()
FFT = FFTFeatures(INTR, FeatureConfig())


def test_maps_are_float32_nan_outside_mask():
    s = synthetic.sphere(INTR, 0.5, 0.15)
    maps = FFT.range_features(s.range_m, s.mask)
    assert isinstance(maps, Eccentricities) and maps.iterations == 0 and np.isnan(maps.residual)
    for m in (maps.eps0, maps.eps2):
        assert m.dtype == np.float32 and m.shape == INTR.shape
        assert np.all(np.isnan(m[~s.mask])) and np.all(np.isfinite(m[s.mask]))


def test_offset_invariant_and_quadratic_in_amplitude():
    """A(0) = 0: adding a constant changes nothing; scaling the surface by 2 scales eps by 4."""
    s = synthetic.sphere(INTR, 0.5, 0.15)
    a = FFT.range_features(s.range_m, s.mask)
    ray_z = INTR.unit_rays()[..., 2]
    b = FFT.range_features(s.range_m + 0.2 / ray_z, s.mask)  # depth + 0.2 m
    np.testing.assert_allclose(b.eps0[s.mask], a.eps0[s.mask], rtol=1e-3, atol=1e-12)


def test_sphere_apex_symmetric_and_fft_grows_with_distance():
    apex = []
    for d in (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9):
        s = synthetic.sphere(INTR, d, 0.15)
        maps = FFT.range_features(s.range_m, s.mask)
        apex.append(maps.eps0[72, 88])
        assert maps.eps2[72, 88] < 1e-6 * maps.eps0[72, 88]
    assert np.all(np.diff(apex) > 0)


def test_fronto_parallel_plane_gives_zero():
    p = synthetic.tilted_plane(INTR, 0.5, 0.0, 0.0)
    pts = INTR.backproject(p.range_m)
    mask = np.hypot(pts[..., 0], pts[..., 1]) < 0.12
    maps = FFT.range_features(p.range_m, mask)
    assert np.nanmax(maps.eps0) < 1e-20 and np.nanmax(maps.eps2) < 1e-20


def test_no_wraparound_from_the_opposite_border():
    """Foreground touching the left border must not feel a bump at the right border."""
    mask = np.zeros(INTR.shape, bool)
    mask[:, :40] = True
    flat = np.full(INTR.shape, 0.5)
    bump = flat.copy()
    bump[:, -10:] = 0.3
    a = FFT.range_features(flat, mask)
    b = FFT.range_features(bump, mask | (np.arange(INTR.width) >= INTR.width - 10)[None, :])
    np.testing.assert_allclose(b.eps0[:, :10], a.eps0[:, :10], atol=1e-15)


def test_amplitude_features_are_gain_invariant():
    s = synthetic.sphere(INTR, 0.5, 0.15)
    a = FFT.amplitude_features(s.amplitude, s.mask)
    b = FFT.amplitude_features(7.0 * s.amplitude, s.mask)
    np.testing.assert_allclose(b.eps0[s.mask], a.eps0[s.mask], rtol=1e-6)
    assert np.nanmax(a.eps0) > 0


def test_empty_mask_and_bad_shapes():
    empty = np.zeros(INTR.shape, bool)
    assert np.all(np.isnan(FFT.range_features(np.ones(INTR.shape), empty).eps0))
    with pytest.raises(ValueError, match="range_m"):
        FFT.range_features(np.ones((10, 10)), empty)
    with pytest.raises(ValueError, match="mask"):
        FFT.amplitude_features(np.ones(INTR.shape), np.ones(INTR.shape))
