import numpy as np
import pytest
import scipy.fft as sfft

from drivers.intrinsics import Intrinsics
from tofd.algorithm.features.transfer import (
    pixel_frequencies_per_m,
    radial_tuning,
    transfer_functions,
    unit_square_m,
)
from tofd.config import ConfigError, FeatureConfig, config_from_dict

CFG = FeatureConfig()


def band(cfg: FeatureConfig) -> tuple[float, float]:
    """The filter's (rho0, sigma) in cycles per metre."""
    return cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m


def test_tuning_peaks_at_rho0_without_lowpass_and_vanishes_at_zero():
    cfg = FeatureConfig(lowpass_sigma_per_m=1e9)
    rho = np.linspace(0, 100, 100001)
    a = radial_tuning(rho, *band(cfg))
    assert a[0] == 0
    assert rho[np.argmax(a)] == pytest.approx(cfg.tuning_frequency_per_m, abs=1e-3)
    assert a.max() == pytest.approx(1.0)
    # near 0 it grows like rho^2 (so planes give exactly zero)
    assert radial_tuning(0.02, *band(cfg)) / radial_tuning(0.01, *band(cfg)) == pytest.approx(4.0, rel=1e-3)


def test_lowpass_attenuates_high_frequencies():
    assert radial_tuning(60.0, *band(CFG)) < 0.5 * radial_tuning(60.0, *band(FeatureConfig(lowpass_sigma_per_m=1e9)))


def test_filters_are_even_and_rotate_like_cos_sin_2theta():
    kx = np.array([7.0, 0.0, 5.0, -7.0])
    ky = np.array([0.0, 7.0, 5.0, 0.0])
    c0, c2, s2 = transfer_functions(kx, ky, *band(CFG))
    a = radial_tuning(7.0, *band(CFG))
    np.testing.assert_allclose(c0[:2], [a, a])
    np.testing.assert_allclose(c2[:2], [-a, a])  # i^2 cos(2 theta): theta = 0 and 90 degrees
    assert s2[2] == pytest.approx(-radial_tuning(np.hypot(5, 5), *band(CFG)))  # theta = 45 degrees
    np.testing.assert_allclose(transfer_functions(-kx, -ky, *band(CFG)), transfer_functions(kx, ky, *band(CFG)),
                               atol=1e-15)
    np.testing.assert_allclose(c0 ** 2, c2 ** 2 + s2 ** 2, atol=1e-15)


def test_fft_and_nfft_frequencies_are_the_same_physical_grid():
    """A mode of the NFFT square and the matching FFT frequency of a full-image grid give the same cycles/m."""
    intr = Intrinsics()
    e = CFG.equivalence_range_m
    lx, ly = unit_square_m(intr, e)
    assert lx == pytest.approx(2 * e * np.tan(np.radians(47.5 / 2)))
    # FFT over exactly the image width: bin k is k cycles per image = k / lx cycles per metre at e
    fx, fy = pixel_frequencies_per_m(sfft.fftfreq(intr.width)[3], sfft.fftfreq(intr.height)[5], intr, e)
    assert fx == pytest.approx(3 / lx) and fy == pytest.approx(5 / ly)


def test_feature_config_validation_names_key():
    for key, value in [("grid_size", 63), ("cg_tolerance", 0.0), ("damping", -1.0), ("cg_max_iterations", 0)]:
        with pytest.raises(ConfigError, match=f"features.{key}"):
            config_from_dict({"features": {key: value}})
