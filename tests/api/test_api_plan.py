"""The public functions on a stream of frames: one set-up per camera and config (FeaturePlan and its cache), the
result types, the FFT path's input, and the warnings for what the NFFT path cannot measure."""

import threading
import warnings

import numpy as np
import pytest

import tofd
from tofd.algorithm.features import FFTFeatures, NFFTFeatures
from tofd.algorithm.features.transfer import pixel_frequencies_per_m, transfer_functions
from tofd.lab import shapes
from tofd.plan import PLANS_KEPT, cached_plan

CAMERA = tofd.Intrinsics(width=320, height=240, fx=228.5, fy=228.5, cx=159.5, cy=119.5)
APEX = (120, 160)


def sphere(distance: float = 0.5, radius: float = 0.1) -> np.ndarray:
    return shapes.sphere(CAMERA, distance, radius).range_m


@pytest.mark.parametrize("method", ["fft", "nfft"])
def test_frame_after_frame_one_plan_is_made_and_gives_the_engines_numbers(method):
    cached_plan.cache_clear()
    frames = [sphere(d) for d in (0.45, 0.5, 0.55)]
    results = [tofd.eccentricities(r, CAMERA, method=method) for r in frames]
    info = cached_plan.cache_info()
    assert (info.misses, info.hits) == (1, 2)
    engine = (FFTFeatures if method == "fft" else NFFTFeatures)(CAMERA, tofd.FeatureConfig())
    plan = tofd.FeaturePlan(CAMERA, method=method)
    for r, result in zip(frames, results, strict=True):
        mask = np.isfinite(r)
        reference = engine.range_features(r, mask)
        kept = plan.eccentricities(r)
        for got, held, want in ((result.eps0, kept.eps0, reference.eps0), (result.eps2, kept.eps2, reference.eps2)):
            assert got.dtype == np.float64 and held.dtype == np.float64
            np.testing.assert_array_equal(got, held)
            scale = np.nanmax(reference.eps0)
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * scale, equal_nan=True)
        assert result.iterations == reference.iterations


def test_the_cache_is_bounded_and_keyed_by_camera_config_and_method():
    cached_plan.cache_clear()
    r = sphere()
    for i in range(PLANS_KEPT + 2):
        tofd.eccentricities(r, CAMERA, method="fft", config=tofd.FeatureConfig(tuning_frequency_per_m=20.0 + i))
    assert cached_plan.cache_info().currsize == PLANS_KEPT
    tofd.eccentricities(r, CAMERA, method="fft", config=tofd.FeatureConfig(fft_input="range"))
    tofd.eccentricities(r, CAMERA, method="fft", config=tofd.FeatureConfig(fft_input="range"))
    assert cached_plan.cache_info().hits == 1


def test_results_unpack_and_surface_filter_results_are_float64():
    r = sphere()
    eps0, eps2 = tofd.eccentricities(r, CAMERA)
    assert eps0.dtype == eps2.dtype == np.float64 and eps0.shape == CAMERA.shape
    c2, s2 = tofd.surface_filter(r, CAMERA, tofd.eccentricity_transfer(2))
    assert c2.dtype == np.float64
    np.testing.assert_allclose(c2**2 + s2**2, eps2, rtol=1e-2, atol=1e-3 * np.nanmax(eps0), equal_nan=True)


def test_equal_eccentricity_transfers_share_a_plans_set_up():
    assert tofd.eccentricity_transfer(2) == tofd.eccentricity_transfer(2) != tofd.eccentricity_transfer(3)
    plan = tofd.FeaturePlan(CAMERA, method="fft")
    plan.surface_filter(sphere(), tofd.eccentricity_transfer(2))
    plan.surface_filter(sphere(0.6), tofd.eccentricity_transfer(2))
    assert len(plan._operators) == 1


def reference_range_fields(range_m: np.ndarray, mask: np.ndarray, cfg: tofd.FeatureConfig) -> np.ndarray:
    """[c0, c2, s2] of the radial range map itself (the paper's baseline), by numpy's FFT of the whole frame padded
    by 128 pixels of background (the mask's largest range)."""
    pad = 128
    image = np.full((CAMERA.height + 2 * pad, CAMERA.width + 2 * pad), np.max(range_m[mask]))
    image[pad:-pad, pad:-pad][mask] = range_m[mask]
    kx, ky = pixel_frequencies_per_m(np.fft.fftfreq(image.shape[1])[None, :], np.fft.fftfreq(image.shape[0])[:, None],
                                     CAMERA, cfg.equivalence_range_m)
    spectrum = np.fft.fft2(image)
    filters = transfer_functions(kx, ky, cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
    return np.stack([np.fft.ifft2(spectrum * f).real[pad:-pad, pad:-pad] for f in filters])


def test_fft_input_range_filters_the_range_map_as_the_paper_and_z_the_depth():
    cfg = tofd.FeatureConfig()
    r = sphere()
    mask = np.isfinite(r)
    c0, c2, s2 = reference_range_fields(r, mask, cfg)
    paper = tofd.eccentricities(r, CAMERA, method="fft", config=tofd.FeatureConfig(fft_input="range"))
    scale = np.max(c0[mask] ** 2)
    np.testing.assert_allclose(paper.eps0[mask], c0[mask] ** 2, rtol=1e-6, atol=1e-7 * scale)
    np.testing.assert_allclose(paper.eps2[mask], (c2**2 + s2**2)[mask], rtol=1e-6, atol=1e-7 * scale)
    depth = tofd.eccentricities(r, CAMERA, method="fft")  # z: the NFFT path's surface at the equivalence range
    nfft = tofd.eccentricities(r, CAMERA)
    assert abs(depth.eps0[APEX] / nfft.eps0[APEX] - 1) < 0.1
    assert paper.eps0[APEX] > 1.2 * depth.eps0[APEX]  # range adds the curvature of the rays' fan
    with pytest.raises(ValueError, match="fft_input"):
        tofd.FeatureConfig(fft_input="depth")


def test_points_outside_the_nfft_patch_warn_with_their_share():
    camera = tofd.Intrinsics(width=640, height=576, fx=504.0, fy=504.0, cx=319.5, cy=287.5)
    plane = tofd.range_from_depth(np.full(camera.shape, 1.2), camera, scale=1.0)
    with pytest.warns(tofd.PatchWarning, match="lie outside the") as caught:
        eps0, _ = tofd.eccentricities(plane, camera)
    nan = int(np.count_nonzero(np.isnan(eps0)))
    assert f"{nan} of {eps0.size} points" in str(caught[0].message) and nan > eps0.size // 2
    with warnings.catch_warnings():
        warnings.simplefilter("error", tofd.PatchWarning)
        tofd.eccentricities(sphere(), CAMERA)  # a 0.1 m sphere fits the patch


def test_an_operator_beyond_the_band_warns_and_a_tapered_one_does_not():
    def hard_laplacian(kx, ky):
        return -(2 * np.pi) ** 2 * (kx**2 + ky**2)

    def laplacian_of_gaussian(kx, ky):
        k2 = kx**2 + ky**2
        return -(2 * np.pi) ** 2 * k2 * np.exp(-k2 / (2 * 20.0**2))

    r = sphere()
    with pytest.warns(tofd.BandWarning, match="beyond the band edge"):
        tofd.surface_filter(r, CAMERA, hard_laplacian)
    with warnings.catch_warnings():
        warnings.simplefilter("error", tofd.BandWarning)
        tofd.surface_filter(r, CAMERA, laplacian_of_gaussian)
        tofd.surface_filter(r, CAMERA, hard_laplacian, method="fft")  # the pixel grid: no damped fit


def test_threads_sharing_a_plan_get_their_own_frames_results():
    plan = tofd.FeaturePlan(CAMERA)
    frames = [sphere(d) for d in (0.4, 0.5, 0.6, 0.7)]
    alone = [plan.eccentricities(r).eps0 for r in frames]
    together: dict[int, np.ndarray] = {}

    def run(i: int) -> None:
        together[i] = plan.eccentricities(frames[i]).eps0

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(frames))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, eps0 in enumerate(alone):
        np.testing.assert_array_equal(together[i], eps0)


def test_a_plan_names_bad_arguments():
    with pytest.raises(ValueError, match="method"):
        tofd.FeaturePlan(CAMERA, method="dft")
    with pytest.raises(ValueError, match="intrinsics"):
        tofd.FeaturePlan((320, 240))
    with pytest.raises(ValueError, match="transfer must be a callable"):
        tofd.FeaturePlan(CAMERA).surface_filter(sphere(), 3.0)
