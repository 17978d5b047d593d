"""The lens model of Intrinsics: validation, rays and projection against OpenCV, storage in tofd's MCAP."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording import format as fmt
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.recording.schemas import CameraCalibration
from tofd_testing.recording_helpers import assert_frames_equal, write_recording

# an Azure Kinect NFOV-unbinned-like depth lens (strong barrel distortion) and a fisheye lens
K4A_LIKE = Intrinsics(640, 576, 504.2, 504.4, 321.3, 329.8, "rational_polynomial",
                      (0.513, 0.167, 0.00011, -0.00007, 0.0055, 0.846, 0.271, 0.0255))
PLUMB_BOB = Intrinsics(320, 240, 260.0, 261.0, 161.2, 118.7, "plumb_bob", (-0.28, 0.09, 0.0012, -0.0008, -0.012))
FISHEYE = Intrinsics(320, 240, 150.0, 150.5, 159.5, 119.5, "equidistant", (0.08, -0.015, 0.002, -0.0003))
LENSES = {"rational": K4A_LIKE, "plumb_bob": PLUMB_BOB, "equidistant": FISHEYE}


def camera_matrix(i: Intrinsics) -> np.ndarray:
    return np.array([[i.fx, 0, i.cx], [0, i.fy, i.cy], [0, 0, 1.0]])


def pixel_grid(i: Intrinsics) -> np.ndarray:
    v, u = np.indices(i.shape, dtype=np.float64)
    return np.stack([u, v], axis=-1)


def test_pinhole_rays_are_the_plain_pinhole_formula():
    i = Intrinsics()
    uv = pixel_grid(i)
    x, y = (uv[..., 0] - i.cx) / i.fx, (uv[..., 1] - i.cy) / i.fy
    rays = np.stack([x, y, np.ones_like(x)], axis=-1)
    np.testing.assert_array_equal(i.unit_rays(), rays / np.linalg.norm(rays, axis=-1, keepdims=True))
    assert i.unit_rays() is i.unit_rays() and not i.unit_rays().flags.writeable
    points = i.unit_rays() * 0.7
    np.testing.assert_array_equal(i.project(points), np.stack(
        [i.fx * points[..., 0] / points[..., 2] + i.cx, i.fy * points[..., 1] / points[..., 2] + i.cy], axis=-1))


@pytest.mark.parametrize("name", LENSES)
def test_rays_undo_the_distortion_like_opencv(name):
    i = LENSES[name]
    rays = i.unit_rays()
    assert np.all(np.isfinite(rays)) and np.allclose(np.linalg.norm(rays, axis=-1), 1.0)
    points = pixel_grid(i).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    if i.distortion_model == "equidistant":
        ref = cv2.fisheye.undistortPoints(points, camera_matrix(i), np.array(i.distortion), criteria=criteria)
    else:
        ref = cv2.undistortPoints(points, camera_matrix(i), np.array(i.distortion), criteria=criteria)
    np.testing.assert_allclose(rays[..., :2] / rays[..., 2:], ref.reshape(*i.shape, 2), rtol=0, atol=1e-9)
    # the corners are far from where a pinhole would put them: the lens model matters there
    plain = Intrinsics(i.width, i.height, i.fx, i.fy, i.cx, i.cy).unit_rays()
    assert np.degrees(np.arccos(np.clip(np.sum(rays[0, 0] * plain[0, 0]), -1, 1))) > 2.0


@pytest.mark.parametrize("name", LENSES)
def test_project_applies_the_distortion_like_opencv_and_inverts_the_rays(name):
    i = LENSES[name]
    rng = np.random.default_rng(1)
    points = i.unit_rays()[::7, ::7].reshape(-1, 3) * rng.uniform(0.3, 3.0, size=(1, 1))
    if i.distortion_model == "equidistant":
        ref, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera_matrix(i),
                                           np.array(i.distortion))
    else:
        ref, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera_matrix(i), np.array(i.distortion))
    np.testing.assert_allclose(i.project(points), ref.reshape(-1, 2), rtol=0, atol=1e-6)
    np.testing.assert_allclose(i.project(i.unit_rays() * 1.3), pixel_grid(i), rtol=0, atol=1e-8)
    uv = np.array([[3.25, 7.5], [161.0, 100.25]])
    np.testing.assert_allclose(i.project(i.pixel_rays(uv[:, 0], uv[:, 1])), uv, atol=1e-8)
    np.testing.assert_allclose(i.project(i.pixel_rays(3.25, 7.5)), uv[0], atol=1e-8)  # scalars too


@pytest.mark.parametrize("lens", [Intrinsics(), *LENSES.values()], ids=["pinhole", *LENSES])
def test_project_point_is_project_of_one_point(lens):
    for xyz in [(0.012, -0.034, 0.41), (-0.3, 0.2, 1.7)]:
        u, v = lens.project_point(xyz)
        assert isinstance(u, float) and isinstance(v, float)
        np.testing.assert_allclose((u, v), lens.project(np.array(xyz)), rtol=0, atol=1e-9)


def test_radial_range_from_z_depth_goes_along_the_lens_rays():
    z = np.full(K4A_LIKE.shape, 1.5)
    radial = K4A_LIKE.radial_from_z(z)
    np.testing.assert_allclose(K4A_LIKE.backproject(radial)[..., 2], 1.5, rtol=1e-12)
    assert radial[0, 0] > 1.5 * 1.4  # a corner ray of this lens is over 45 degrees off axis


def test_pixel_beyond_where_the_lens_folds_back_has_no_ray():
    # k1 < 0 alone: the distorted radius peaks at r = 1/sqrt(3 |k1|) and no ray reaches beyond that
    i = Intrinsics(200, 10, 50.0, 50.0, 0.0, 4.5, "plumb_bob", (-0.25, 0.0, 0.0, 0.0, 0.0))
    peak_px = 50.0 * (1 / np.sqrt(0.75)) * (1 - 0.25 / 0.75)
    rays = i.unit_rays()
    u = np.arange(200)
    assert np.all(np.isfinite(rays[4, u < peak_px - 1])) and np.all(np.isnan(rays[4, u > peak_px + 1]))


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"width": 0}, "width"), ({"height": 9000}, "height"), ({"width": 10.5}, "width"), ({"height": True}, "height"),
    ({"fx": 0.0}, "fx"), ({"fy": float("nan")}, "fy"), ({"cx": float("inf")}, "cx"), ({"cy": "1"}, "cy"),
    ({"distortion_model": "fisheye"}, "distortion_model"),
    ({"distortion_model": "plumb_bob", "distortion": (0.1, 0.2)}, "distortion"),
    ({"distortion": (0.1,)}, "distortion"),
    ({"distortion_model": "equidistant", "distortion": (0.1, 0.0, float("nan"), 0.0)}, "distortion"),
])
def test_validation_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=rf"^intrinsics\.{field}: "):
        Intrinsics(**kwargs)


def test_dict_round_trip_and_dicts_from_before_lens_models():
    for i in (*LENSES.values(), Intrinsics()):
        assert Intrinsics.from_dict(i.to_dict()) == i
    old = {"width": 40, "height": 30, "fx": 50.0, "fy": 50.0, "cx": 19.5, "cy": 14.5}
    assert Intrinsics.from_dict(old).distortion_model == "none" and Intrinsics().to_dict().keys() == old.keys()
    with pytest.raises(ValueError, match="unknown intrinsics key"):
        Intrinsics.from_dict({**old, "k1": 0.1})


def test_tofd_recording_keeps_the_lens_and_tells_foxglove(tmp_path):
    path = tmp_path / "r.mcap"
    lens = Intrinsics(176, 144, 150.0, 151.0, 88.2, 71.9, "rational_polynomial", K4A_LIKE.distortion)
    frames = write_recording(path, range(3), quantized=False, intrinsics=lens)
    replayed = list(iter_frames(path))
    for a, b in zip(frames, replayed, strict=True):
        assert_frames_equal(a, b)
    assert read_recording_info(path).intrinsics == lens
    with open(path, "rb") as f:
        calibrations = [CameraCalibration.FromString(m.data) for _, c, m in make_reader(f).iter_messages()
                        if c.topic == "/camera/calibration"]
    assert len(calibrations) == 3
    assert {c.distortion_model for c in calibrations} == {"rational_polynomial"}
    assert [list(c.D) for c in calibrations] == [list(lens.distortion)] * 3


def test_pinhole_frames_are_encoded_as_before_lens_models():
    # a pinhole header carries no distortion fields, and Foxglove gets plumb_bob with zero coefficients
    from tofd_testing.recording_helpers import make_frame
    messages = fmt.encode_frame(make_frame(2))
    header = fmt.schemas.frame_header_class().FromString(messages[0])
    assert not header.intrinsics.HasField("distortion_model") and len(header.intrinsics.distortion) == 0
    calibration = CameraCalibration.FromString(messages[3])
    assert calibration.distortion_model == "plumb_bob" and list(calibration.D) == [0.0] * 5
    assert fmt.decode_frame(*messages[:3]).intrinsics == Intrinsics()


def test_the_config_takes_a_lens_and_names_a_bad_one():
    from tofd.config import ConfigError, config_from_dict, config_table

    table = {"intrinsics": {**PLUMB_BOB.to_dict()}}
    cfg = config_from_dict(table)
    assert cfg.intrinsics == PLUMB_BOB and config_from_dict(config_table(cfg)) == cfg
    with pytest.raises(ConfigError, match=r"intrinsics\.distortion: model 'plumb_bob' takes 5"):
        config_from_dict({"intrinsics": {"distortion_model": "plumb_bob"}})
    with pytest.raises(ConfigError, match=r"intrinsics\.distortion_model: 'fisheye' is not one of"):
        config_from_dict({"intrinsics": {"distortion_model": "fisheye"}})
