"""The same surface gives the same NFFT features from every camera: analytic spheres and ellipsoids (ray-surface
intersection) seen by the SR3000, a 320x240 70-degree camera, a 640x576 (fx 504) and a 1024x1024 (fx 500) one."""

import dataclasses
import math

import numpy as np
import pytest

from tofd.algorithm.detector.model_file import ModelMismatch, NoseModel
from tofd.algorithm.features import NFFTFeatures, SamplingError
from tofd.algorithm.features.sampling import farthest_range_m
from tofd.config import FeatureConfig, SegmentationConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic

CFG = FeatureConfig()


def camera(width: int, height: int, *, fov_deg: float | None = None, f: float | None = None) -> Intrinsics:
    if f is None:
        f = (width / 2) / math.tan(math.radians(fov_deg / 2))
    return Intrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


CAMERAS = {"sr3000": Intrinsics(), "320x240@70": camera(320, 240, fov_deg=70.0),
           "640x576": camera(640, 576, f=504.0), "1024x1024": camera(1024, 1024, f=500.0)}


def ellipsoid(intr: Intrinsics, apex_m: float, semi_axes: tuple[float, float, float]) -> np.ndarray:
    """Radial range (NaN = miss) of an axis-aligned ellipsoid whose nearest point lies on the optical axis at apex_m."""
    axes = np.asarray(semi_axes)
    centre = np.array([0.0, 0.0, apex_m + axes[2]])
    rays = intr.unit_rays()
    d, c = rays / axes, centre / axes  # the unit sphere in scaled coordinates
    b, cc = d @ c, c @ c - 1.0
    a = np.einsum("hwc,hwc->hw", d, d)
    disc = b * b - a * cc
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0, (b - np.sqrt(disc)) / a, np.nan)


def apex_value(intr: Intrinsics, range_m: np.ndarray, name: str) -> float:
    """The feature at the pixel nearest the apex (on the optical axis)."""
    maps = NFFTFeatures(intr, CFG).range_features(range_m, np.isfinite(range_m))
    return float(getattr(maps, name)[int(round(intr.cy)), int(round(intr.cx))])


@pytest.mark.parametrize("distance", [0.35, 0.5, 0.8])
def test_sphere_apex_eps0_is_the_same_from_every_camera(distance):
    values = {name: apex_value(intr, synthetic.sphere(intr, distance, 0.1).range_m, "eps0")
              for name, intr in CAMERAS.items()}
    ref = values["sr3000"]
    assert ref > 0
    for name, value in values.items():
        assert value == pytest.approx(ref, rel=0.02), name


@pytest.mark.parametrize("distance", [0.35, 0.5, 0.8])
def test_ellipsoid_apex_eps0_and_eps2_are_the_same_from_every_camera(distance):
    """Curvatures 1/0.1 and 1/0.05 along x and y at the apex: eps2 is far from 0 (a sphere's is ~0)."""
    values = {name: [apex_value(intr, ellipsoid(intr, distance, (0.1, math.sqrt(0.1 * 0.05), 0.1)), n)
                     for n in ("eps0", "eps2")] for name, intr in CAMERAS.items()}
    ref0, ref2 = values["sr3000"]
    assert ref2 > 0.05 * ref0
    for name, (eps0, eps2) in values.items():
        assert eps0 == pytest.approx(ref0, rel=0.02), name
        assert eps2 == pytest.approx(ref2, rel=0.02), name


def test_sphere_apex_eps0_is_the_same_at_every_distance():
    values = [apex_value(intr, synthetic.sphere(intr, d, 0.1).range_m, "eps0")
              for intr in CAMERAS.values() for d in (0.35, 0.5, 0.8)]
    assert max(values) / min(values) < 1.02


def test_too_coarse_sampling_is_refused_and_the_limit_is_where_values_start_to_drift():
    """Past farthest_range_m the features are refused; just inside it the apex eps0 is still within 2 %."""
    intr = CAMERAS["sr3000"]
    limit = farthest_range_m(intr, CFG)
    assert 1.0 < limit < 1.5
    near = apex_value(intr, synthetic.sphere(intr, 0.5, 0.1).range_m, "eps0")
    inside = apex_value(intr, synthetic.sphere(intr, limit - 0.1, 0.1).range_m, "eps0")
    assert inside == pytest.approx(near, rel=0.02)
    far = synthetic.sphere(intr, limit + 0.05, 0.1).range_m
    with pytest.raises(SamplingError, match="range_m: the foreground at .* too coarse"):
        NFFTFeatures(intr, CFG).range_features(far, np.isfinite(far))
    # a grid that reaches past what the pixels carry is refused at 0.5 m (it used to give a wrong, converged value)
    big = dataclasses.replace(CFG, grid_size=256)
    near_scene = synthetic.sphere(intr, 0.5, 0.1).range_m
    with pytest.raises(SamplingError):
        NFFTFeatures(intr, big).range_features(near_scene, np.isfinite(near_scene))


def test_model_files_without_patch_keys_read_as_the_sr3000_patch():
    """A model recorded before the patch was metric matches today's defaults; another patch is a mismatch."""
    recorded = dataclasses.asdict(CFG)
    del recorded["patch_width_m"], recorded["patch_height_m"]
    model = NoseModel({}, recorded, dataclasses.asdict(SegmentationConfig()))
    model.check_compatible(CFG, SegmentationConfig())
    with pytest.raises(ModelMismatch, match="features.patch_width_m"):
        model.check_compatible(dataclasses.replace(CFG, patch_width_m=0.4), SegmentationConfig())


@pytest.mark.slow
@pytest.mark.parametrize("distance", [0.35, 0.8])
def test_a_face_patch_gives_the_same_features_from_every_camera(distance):
    """The rendered head's eps0 at the tip within 2 % of the finest camera's (beside it, where it is 30-50x smaller,
    within 5 %), eps2 at the tip within 2 % of the tip's eps0: the fields read at the same surface points
    (tofd.lab.face_patch), averaged over sampling phases where coarse pixels alias the point-sampled mesh (fewer
    phases for the finer pixels)."""
    from tofd.lab.face_patch import PHASES_PX, read_patch

    ref = read_patch("1024x1024", CAMERAS["1024x1024"], distance, CFG, phases_px=PHASES_PX[:4])
    for name, phases in (("sr3000", PHASES_PX), ("320x240@70", PHASES_PX), ("640x576", PHASES_PX[:4])):
        r = read_patch(name, CAMERAS[name], distance, CFG, phases_px=phases)
        assert r.eps0[0] == pytest.approx(ref.eps0[0], rel=0.02), name
        np.testing.assert_allclose(r.eps0[1:], ref.eps0[1:], rtol=0.05, err_msg=name)
        assert abs(r.eps2[0] - ref.eps2[0]) <= 0.02 * ref.eps0[0], name


def test_the_pipeline_leaves_nfft_maps_nan_with_a_warning_where_the_camera_is_too_coarse():
    """The feature extractor (the pipeline's workers) does not stop on such a frame: its FFT maps are computed, its
    NFFT maps are NaN (no NFFT detection from wrong numbers) and a RuntimeWarning says why."""
    from tofd.algorithm.extract import FeatureExtractor

    intr = CAMERAS["sr3000"]
    wall = synthetic.tilted_plane(intr, 2.5, 0.0, 0.0)
    extractor = FeatureExtractor(intr, CFG, SegmentationConfig())
    near = synthetic.sphere(intr, 0.5, 0.1).over(wall)
    maps = extractor(near.range_m, near.amplitude).maps
    assert np.isfinite(maps["range_nfft_eps0"]).any()
    far = synthetic.sphere(intr, farthest_range_m(intr, CFG) + 0.1, 0.1).over(wall)
    with pytest.warns(RuntimeWarning, match="NFFT features left out: range_m: the foreground at"):
        features = extractor(far.range_m, far.amplitude)
    assert np.isfinite(features.maps["range_fft_eps0"]).any()
    assert np.isnan(features.maps["range_nfft_eps0"]).all() and np.isnan(features.maps["amp_nfft_eps2"]).all()
