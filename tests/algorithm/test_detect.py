"""The box learner, box distance, detection on maps, and the model file."""

import dataclasses
import json

import cv2
import numpy as np
import pytest

from tofd.algorithm.detector import (
    VARIANTS,
    Box,
    Candidates,
    Margin,
    ModelError,
    ModelMismatch,
    NoseModel,
    VariantModel,
    border_distance_m,
    depth_noise_m,
    detect,
    front_gap_m,
    learn_box,
    load_model,
    rival_distance,
    save_model,
    stack_features,
)
from tofd.config import FeatureConfig, SegmentationConfig
from tofd.drivers.intrinsics import Intrinsics


def test_box_of_uniform_cloud_matches_its_quantiles():
    rng = np.random.default_rng(0)
    lo, hi = np.array([-3.0, 1.0]), np.array([-1.0, 5.0])
    samples = lo + (hi - lo) * rng.random((200_000, 2))
    box = learn_box(samples, ("a", "b"), quantile=0.1)
    # quantiles 0.1 / 0.9 of U(lo, hi): lo + 0.1 (hi - lo), hi - 0.1 (hi - lo)
    np.testing.assert_allclose(box.centre, (lo + hi) / 2, atol=0.01)
    np.testing.assert_allclose(box.half_width, 0.4 * (hi - lo), atol=0.01)


def test_box_ignores_outliers_and_nan():
    rng = np.random.default_rng(1)
    samples = rng.normal([0.0, 10.0], [1.0, 0.1], size=(10_000, 2))
    samples[:20] = 1e6  # 0.2 % gross outliers
    samples[20:40, 0] = np.nan
    box = learn_box(samples, ("a", "b"), quantile=0.05)
    np.testing.assert_allclose(box.centre, [0.0, 10.0], atol=0.05)
    np.testing.assert_allclose(box.half_width, [1.645, 0.1645], rtol=0.05)


def test_box_distance_is_normalised_chebyshev():
    box = Box(("a", "b"), np.array([0.0, 0.0]), np.array([1.0, 2.0]))
    x = np.array([[0.5, 0.0], [0.0, 3.0], [2.0, 2.0], [np.nan, 0.0]])
    np.testing.assert_allclose(box.distance(x), [0.5, 1.5, 2.0, np.inf])


def test_learner_separates_two_clouds_of_a_known_layout():
    rng = np.random.default_rng(2)
    nose = rng.normal([1.0, -1.0], 0.1, size=(5000, 2))
    other = rng.normal([0.0, 0.0], 0.1, size=(5000, 2))
    box = learn_box(nose, ("a", "b"), quantile=0.01)
    assert np.mean(box.distance(nose) <= 1) == pytest.approx(0.98**2, abs=0.01)  # 98 % per feature
    assert np.mean(box.distance(other) <= 1) == 0.0


def test_detect_finds_the_pixel_in_the_box():
    h, w = 6, 8
    maps = {n: np.full((h, w), 1e-3, np.float32) for n in VARIANTS["nfft_range"]}
    maps["range_nfft_eps0"][2, 5] = 1.0  # the only pixel near the box centre (log10 0, -3)
    maps["range_nfft_eps0"][0, 0] = np.nan
    box = Box(VARIANTS["nfft_range"], np.array([0.0, -3.0]), np.array([0.5, 0.5]))
    intrinsics = Intrinsics(width=w, height=h, fx=10.0, fy=10.0, cx=3.5, cy=2.5)
    range_m = np.linspace(0.4, 0.6, h * w).reshape(h, w)
    det = detect(maps, range_m, intrinsics, box, scale=1.0)
    assert det.accepted and det.nose_px == (5, 2) and det.score == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(det.nose_xyz_m, intrinsics.backproject(range_m)[2, 5])
    maps["range_nfft_eps0"][2, 5] = 10.0  # log10 = 1: distance 2 > scale 1
    det = detect(maps, range_m, intrinsics, box, scale=1.0)
    assert not det.accepted and det.nose_px is None and det.score == pytest.approx(2.0)


def test_margin_accepts_a_clear_winner_beyond_the_scale_and_rejects_a_close_race():
    h, w = 20, 40
    intrinsics = Intrinsics(width=w, height=h, fx=50.0, fy=50.0, cx=19.5, cy=9.5)
    range_m = np.full((h, w), 0.5)  # a pixel spans 1 cm: the rival radius (2 cm) is two pixels
    box = Box(VARIANTS["nfft_range"], np.array([0.0, -3.0]), np.array([0.5, 0.5]))
    maps = {n: np.full((h, w), 1e-3, np.float32) for n in VARIANTS["nfft_range"]}  # eps0 log10 -3: distance 6
    maps["range_nfft_eps0"][10, 10] = 10**0.6  # distance 1.2: beyond scale 1, but 5x ahead of every rival
    maps["range_nfft_eps0"][10, 11] = 10**0.65  # its neighbour is not a rival (1 cm away)
    paper, margin = Margin(), Margin(ratio=0.5, scale_factor=1.5)
    assert not detect(maps, range_m, intrinsics, box, 1.0).accepted
    det = detect(maps, range_m, intrinsics, box, 1.0, margin=margin)
    assert det.accepted and det.nose_px == (10, 10) and det.score == pytest.approx(1.2, rel=1e-5)
    maps["range_nfft_eps0"][10, 30] = 10**0.9  # a rival 20 cm away at distance 1.8: 1.2 > 0.5 x 1.8
    det = detect(maps, range_m, intrinsics, box, 1.0, margin=margin)
    assert not det.accepted  # the close race leaves two regions inside the box at 1.5: the track may choose
    assert [(a.px, round(a.score, 3)) for a in det.alternatives] == [((10, 10), 1.2)]  # 1.8 > 1.5: not one
    maps["range_nfft_eps0"][10, 30] = 10**0.7  # distance 1.4
    assert [a.px for a in detect(maps, range_m, intrinsics, box, 1.0, margin=margin).alternatives] == [(10, 10),
                                                                                                       (30, 10)]
    maps["range_nfft_eps0"][10, 30] = 10**0.9
    maps["range_nfft_eps0"][10, 10] = 10**0.48  # distance 0.96: inside the scale, but more than 0.5 x 1.8
    assert detect(maps, range_m, intrinsics, box, 1.0).accepted
    assert not detect(maps, range_m, intrinsics, box, 1.0, margin=margin).accepted
    assert paper.accepts(0.96, 1.8, 1.0) and not margin.accepts(0.96, 1.8, 1.0) and margin.accepts(1.4, np.inf, 1.0)


def test_rival_distance_skips_the_best_pixels_neighbourhood():
    xyz = np.array([[0.0, 0.0, 0.5], [0.01, 0.0, 0.5], [0.0, 0.019, 0.5], [0.03, 0.0, 0.5], [0.0, 0.0, 0.6]])
    distance = np.array([0.1, 0.2, 0.3, 0.9, 0.7])
    assert rival_distance(distance, xyz) == pytest.approx(0.7)  # pixels 1, 2 lie within 2 cm of pixel 0
    assert rival_distance(distance[:3], xyz[:3]) == np.inf


def test_border_distance_is_physical_and_scale_invariant():
    intrinsics = Intrinsics()
    yy, xx = np.mgrid[: intrinsics.height, : intrinsics.width]
    for depth in (0.35, 0.7):
        radius_px = 0.05 * intrinsics.fx / depth  # a disc of 5 cm radius at this depth
        mask = (xx - 88) ** 2 + (yy - 72) ** 2 <= radius_px**2
        range_m = depth / intrinsics.unit_rays()[..., 2]
        border = border_distance_m(mask, range_m, intrinsics)
        assert border[72, 88] == pytest.approx(0.05, abs=0.002)  # the centre: 5 cm from the border, at any depth
        cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
        ring = mask & ~cv2.erode(mask.view(np.uint8), cross).view(bool)  # 4-neighbours of the border
        assert np.all(border[ring] <= 0.5 * depth / intrinsics.fx * 1.001) and np.all(border[~mask] == 0)
    edge = np.zeros((intrinsics.height, intrinsics.width), bool)
    edge[:, :10] = True  # a mask touching the image edge: the edge is a border too
    assert border_distance_m(edge, np.full(edge.shape, 0.5), intrinsics)[72, 0] < 0.002


def test_detect_never_picks_a_pixel_near_the_mask_border():
    h, w = 40, 40
    intrinsics = Intrinsics(width=w, height=h, fx=100.0, fy=100.0, cx=19.5, cy=19.5)
    maps = {n: np.full((h, w), np.nan, np.float32) for n in VARIANTS["nfft_range"]}
    for n in maps:
        maps[n][5:35, 5:35] = 1e-3  # the foreground: a 30 px square
    maps["range_nfft_eps0"][5, 20] = 1.0  # best pixel: on the border (a clamped cap)
    maps["range_nfft_eps0"][20, 20] = 0.5  # second best: inside
    box = Box(VARIANTS["nfft_range"], np.array([0.0, -3.0]), np.array([0.5, 0.5]))
    range_m = np.full((h, w), 0.5)
    assert detect(maps, range_m, intrinsics, box, 1.0).nose_px == (20, 5)
    # 0.5 m / 100 px: 5 mm per pixel; a 2 cm margin excludes the 4 outer pixel rings, not the centre
    det = detect(maps, range_m, intrinsics, box, 1.0, Candidates(border_margin_m=0.02))
    assert det.accepted and det.nose_px == (20, 20)


@pytest.mark.parametrize("depth", [0.35, 0.7])
def test_front_gap_is_the_depth_behind_the_nearest_pixel_within_the_radius(depth):
    """A wall with a 2 cm step, noisy (sigma 2 mm): behind the step the gap is 2 cm within 12 mm of it and 0
    beyond (at any distance); in front of it 0 everywhere (the median filter keeps noise from opening a gap)."""
    intrinsics = Intrinsics()
    rays_z = intrinsics.unit_rays()[..., 2]
    z = np.full(intrinsics.shape, depth)
    z[:, 88:] += 0.02
    rng = np.random.default_rng(0)
    range_m = (z + 0.002 * rng.standard_normal(z.shape)) / rays_z
    mask = np.ones(z.shape, bool)
    gap = front_gap_m(mask, range_m, intrinsics)
    px_per_cm = 0.01 * intrinsics.fx / (depth + 0.01)
    near, far = 88 + int(0.6 * px_per_cm), 88 + int(2.0 * px_per_cm)  # 6 mm and 20 mm behind the step's edge
    assert np.median(gap[20:120, near]) == pytest.approx(0.02, abs=0.002)
    assert np.median(gap[20:120, far]) < 0.002
    assert np.percentile(gap[20:120, 10:85], 99) < 0.004
    assert np.all(front_gap_m(~mask, range_m, intrinsics) == 0)


def test_detect_front_test_rejects_a_pixel_behind_a_nearer_neighbour():
    """The best box pixel lies 2 cm behind its neighbours (the lip under a nose seen from above): with the front
    test the detector takes the second best, on the front surface."""
    h, w = 40, 40
    intrinsics = Intrinsics(width=w, height=h, fx=100.0, fy=100.0, cx=19.5, cy=19.5)
    maps = {n: np.full((h, w), 1e-3, np.float32) for n in VARIANTS["nfft_range"]}
    maps["range_nfft_eps0"][24, 20] = 1.0  # best pixel
    maps["range_nfft_eps0"][15, 20] = 0.5  # second best
    box = Box(VARIANTS["nfft_range"], np.array([0.0, -3.0]), np.array([0.5, 0.5]))
    depth = np.full((h, w), 0.5)
    depth[23:, :] = 0.52  # rows from 23 on: 2 cm behind the rest (5 mm per pixel, front radius 2 px)
    range_m = depth / intrinsics.unit_rays()[..., 2]
    assert detect(maps, range_m, intrinsics, box, 1.0).nose_px == (20, 24)
    assert detect(maps, range_m, intrinsics, box, 1.0, Candidates(front_depth_m=0.008)).nose_px == (20, 15)
    assert detect(maps, range_m, intrinsics, box, 1.0, Candidates(front_depth_m=0.03)).nose_px == (20, 24)


def test_stack_features_names_missing_map():
    with pytest.raises(KeyError, match="amp_fft_eps0"):
        stack_features({"range_fft_eps0": np.ones(3)}, ("range_fft_eps0", "amp_fft_eps0"))


def _model() -> NoseModel:
    boxes = {v: VariantModel(v, Box(names, np.linspace(-2, 1, len(names)), np.full(len(names), 0.25)), 1.3, 0.05)
             for v, names in VARIANTS.items()}
    return NoseModel(boxes, dataclasses.asdict(FeatureConfig()), dataclasses.asdict(SegmentationConfig()),
                     quantile=0.05, positive_radius_mm=5.0, training={"frames": 3})


def test_model_round_trips_through_json(tmp_path):
    model = _model()
    path = save_model(model, tmp_path / "m.json")
    loaded = load_model(path)
    assert loaded.variants.keys() == model.variants.keys()
    for name, vm in model.variants.items():
        got = loaded.variant(name)
        assert got.box.features == vm.box.features and got.operating_scale == vm.operating_scale
        np.testing.assert_allclose(got.box.centre, vm.box.centre, atol=1e-6)
        np.testing.assert_allclose(got.box.half_width, vm.box.half_width, atol=1e-6)
    assert loaded.feature_config == model.feature_config and loaded.training == {"frames": 3}
    loaded.check_compatible(FeatureConfig(), SegmentationConfig())


def test_model_mismatch_names_the_setting():
    model = _model()
    with pytest.raises(ModelMismatch, match="features.equivalence_range_m"):
        model.check_compatible(FeatureConfig(equivalence_range_m=0.7), SegmentationConfig())


def test_bad_model_file_names_the_key(tmp_path):
    d = _model().to_dict()
    d["variants"]["nfft_range"]["box"]["half_width_log10"] = [0.1, -1.0]
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ModelError, match="variants.nfft_range.box"):
        load_model(tmp_path / "bad.json")
    del d["feature_config"]
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(ModelError, match="feature_config"):
        load_model(tmp_path / "bad.json")
    with pytest.raises(ModelError, match="cannot read model"):
        load_model(tmp_path / "absent.json")


def test_shipped_model_matches_the_bundled_config():
    from tofd.config import load_config
    from tofd.service.model import load_detector

    try:
        det = load_detector(load_config())
    except ModelMismatch as exc:
        pytest.fail(f"config/nose_model.json is stale, retrain with the command in tofd/commands/train.py ({exc})")
    assert det.scale > 0 and det.box.features == VARIANTS["nfft_range"]


@pytest.mark.parametrize("sigma", [0.001, 0.004])
def test_depth_noise_estimates_the_noise_of_a_plane(sigma):
    intrinsics = Intrinsics()
    rays_z = intrinsics.unit_rays()[..., 2]
    rng = np.random.default_rng(4)
    range_m = (0.6 + sigma * rng.standard_normal(intrinsics.shape)) / rays_z
    mask = np.zeros(intrinsics.shape, bool)
    mask[30:110, 40:140] = True
    noise = depth_noise_m(mask, range_m, intrinsics)
    assert np.median(noise[40:100, 50:130]) == pytest.approx(sigma, rel=0.15)
    assert np.all(noise[~mask] == 0)


def test_front_test_allowance_grows_with_the_local_noise():
    """A pixel 3 mm behind the front: rejected with the fixed 1 mm allowance, kept where 1 mm + 1 x sigma (4 mm
    noise) covers it, still rejected where the noise is 1 mm."""
    cand = Candidates(front_depth_m=0.001, front_noise_factor=1.0)
    gap, border = np.array([0.003, 0.003]), np.array([1.0, 1.0])
    assert list(Candidates(front_depth_m=0.001).keep(border, gap, np.array([0.004, 0.001]))) == [False, False]
    assert list(cand.keep(border, gap, np.array([0.004, 0.001]))) == [True, False]


def test_rendered_detection_reports_the_tip_and_survives_the_worker_message():
    from tofd.config import load_config
    from tofd.drivers.emulator.render import Pose, render_face
    from tofd.lab.faces import SUBJECTS, make_subject
    from tofd.service.model import load_detector
    from tofd.service.pipeline.stages import detection_dict, detection_from

    detector, intrinsics = load_detector(load_config(None)), Intrinsics()
    r = render_face(make_subject(SUBJECTS["mp_bignose"]), Pose(0.4, 10.0, 5.0), intrinsics,
                    np.random.default_rng(5))
    det = detector.detect_frame(r.range_m, r.amplitude)
    assert det.accepted and det.tip_xyz_m is not None and det.alternatives[0].px == det.nose_px
    assert det.answer_xyz_m == det.tip_xyz_m and det.answer_px == det.tip_px
    assert np.linalg.norm(np.subtract(det.tip_xyz_m, r.nose_xyz_m)) < 0.01
    np.testing.assert_allclose(intrinsics.project(np.asarray(det.tip_xyz_m)), det.tip_px)
    assert detection_from(json.loads(json.dumps(detection_dict(det)))) == det
