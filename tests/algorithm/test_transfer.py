import numpy as np
import pytest
import scipy.fft as sfft

from tofd.algorithm.band import BAND_FLOOR, band_edge_per_m
from tofd.algorithm.features.transfer import (
    eccentricity_filters,
    pixel_frequencies_per_m,
    radial_tuning,
    transfer_functions,
)
from tofd.config import ConfigError, FeatureConfig, config_from_dict
from tofd.drivers.intrinsics import Intrinsics

CFG = FeatureConfig()


def band(cfg: FeatureConfig) -> tuple[float, float]:
    """The filter's (rho0, sigma) in cycles per metre."""
    return cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m


def test_tuning_peaks_at_rho0_without_lowpass_and_vanishes_at_zero():
    no_lowpass = (CFG.tuning_frequency_per_m, 1e9)
    rho = np.linspace(0, 100, 100001)
    a = radial_tuning(rho, *no_lowpass)
    assert a[0] == 0
    assert rho[np.argmax(a)] == pytest.approx(CFG.tuning_frequency_per_m, abs=1e-3)
    assert a.max() == pytest.approx(1.0)
    # near 0 it grows like rho^2 (so planes give exactly zero)
    assert radial_tuning(0.02, *no_lowpass) / radial_tuning(0.01, *no_lowpass) == pytest.approx(4.0, rel=1e-3)


def test_lowpass_attenuates_high_frequencies():
    assert radial_tuning(60.0, *band(CFG)) < 0.5 * radial_tuning(60.0, CFG.tuning_frequency_per_m, 1e9)


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


def test_fft_and_nfft_frequencies_are_the_same_physical_grid_on_the_sr3000():
    """The default NFFT patch is the SR3000's field of view at e: a mode of the patch and the matching FFT frequency of
    a full-image grid give the same cycles/m there."""
    intr = Intrinsics()
    e = CFG.equivalence_range_m
    lx, ly = CFG.patch_width_m, CFG.patch_height_m
    assert lx == pytest.approx(2 * e * np.tan(np.radians(47.5 / 2)), rel=1e-12)
    assert ly == pytest.approx(lx * 144 / 176, rel=1e-12)
    # FFT over exactly the image width: bin k is k cycles per image = k / lx cycles per metre at e
    fx, fy = pixel_frequencies_per_m(sfft.fftfreq(intr.width)[3], sfft.fftfreq(intr.height)[5], intr, e)
    assert fx == pytest.approx(3 / lx) and fy == pytest.approx(5 / ly)


@pytest.mark.parametrize("rho0, sigma", [(30.0, 50.0), (7.0, 12.0), (20.0, 1e9), (40.0, 10.0)])
def test_band_edge_is_where_the_tuning_falls_to_the_floor(rho0, sigma):
    rho = np.linspace(0.0, 20 * rho0, 400001)
    a = radial_tuning(rho, rho0, sigma)
    numeric = rho[a >= BAND_FLOOR * a.max()][-1]
    assert band_edge_per_m(rho0, sigma) == pytest.approx(numeric, abs=2 * rho[1])
    assert band_edge_per_m(rho0, sigma, 0.5) < band_edge_per_m(rho0, sigma)


def test_eccentricity_filters_of_order_0_and_2_are_the_pipeline_filters():
    kx, ky = np.meshgrid(np.linspace(-80, 80, 21), np.linspace(-60, 60, 17))
    c0, c2, s2 = transfer_functions(kx, ky, *band(CFG))
    np.testing.assert_allclose(eccentricity_filters(kx, ky, 0, *band(CFG))[0], c0, atol=1e-15)
    np.testing.assert_allclose(eccentricity_filters(kx, ky, 2, *band(CFG)), [c2, s2], atol=1e-15)
    c3, s3 = eccentricity_filters(kx, ky, 3, *band(CFG))  # odd n: imaginary and odd, Hermitian all the same
    np.testing.assert_allclose(eccentricity_filters(-kx, -ky, 3, *band(CFG)), np.conj([c3, s3]), atol=1e-15)
    np.testing.assert_allclose(np.abs(c3) ** 2 + np.abs(s3) ** 2, c0**2, atol=1e-15)


def test_feature_config_validates_when_constructed():
    for kwargs, key in [({"grid_size": 63}, "grid_size"), ({"cg_precision": "half"}, "cg_precision"),
                        ({"equivalence_range_m": 0}, "equivalence_range_m"), ({"patch_width_m": -0.1}, "patch_width_m"),
                        ({"grid_size": 32}, "grid_size"), ({"lowpass_sigma_per_m": float("nan")}, "lowpass_sigma")]:
        with pytest.raises(ValueError, match=key):
            FeatureConfig(**kwargs)
    with pytest.raises(ValueError, match="band edge"):  # the grid must reach the band over the patch
        FeatureConfig(patch_width_m=1.0)
    assert FeatureConfig(patch_width_m=1.0, patch_height_m=1.0, grid_size=146).grid_nyquist_per_m == (73.0, 73.0)


def test_a_config_tuned_higher_gets_the_least_grid_that_reaches_its_band():
    base = FeatureConfig()
    with pytest.raises(ValueError, match="band edge"):
        FeatureConfig(tuning_frequency_per_m=40.0)  # the default grid falls short of that band
    tuned = base.tuned_to(40.0)
    assert tuned.tuning_frequency_per_m == 40.0 and tuned.grid_size > base.grid_size
    assert min(tuned.grid_nyquist_per_m) >= tuned.band_edge_per_m  # it reaches the band edge ...
    smaller = tuned.grid_size - 2
    assert min(smaller / 2 / tuned.patch_width_m, smaller / 2 / tuned.patch_height_m) < tuned.band_edge_per_m
    assert base.tuned_to(base.tuning_frequency_per_m) == base  # ... and no grid is raised that reaches it already


def test_feature_config_validation_names_key():
    for key, value in [("grid_size", 63), ("cg_tolerance", 0.0), ("damping", -1.0), ("cg_max_iterations", 0),
                       ("patch_height_m", 0.0)]:
        with pytest.raises(ConfigError, match=f"features.{key}"):
            config_from_dict({"features": {key: value}})
