"""Intrinsics from an OpenCV calibration and from a ROS CameraInfo, checked against OpenCV's own undistortion, and
numpy scalars in the public configs."""

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import tofd

K = np.array([[504.0, 0.0, 321.2], [0.0, 503.1, 290.4], [0.0, 0.0, 1.0]])
PLUMB_BOB = np.array([-0.28, 0.09, 0.001, -0.0005, -0.015])
RATIONAL = np.array([0.5, -0.02, 0.001, -0.0005, 0.0, 0.8, 0.05, 0.0])
FISHEYE = np.array([0.1, -0.02, 0.003, -0.001])
EXACT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)


def pixels() -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.arange(0.0, 640.0, 37.0), np.arange(0.0, 576.0, 41.0))
    return u.ravel(), v.ravel()


def normalised(camera: tofd.Intrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    rays = camera.pixel_rays(u, v)
    return rays[:, :2] / rays[:, 2:]


@pytest.mark.parametrize("d", [PLUMB_BOB, RATIONAL], ids=["plumb_bob", "rational_polynomial"])
def test_from_opencv_undistorts_as_opencv_does(d):
    camera = tofd.Intrinsics.from_opencv(K, d, 640, 576)
    assert camera.distortion_model == ("plumb_bob" if len(d) == 5 else "rational_polynomial")
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (504.0, 503.1, 321.2, 290.4)
    u, v = pixels()
    opencv = cv2.undistortPoints(np.stack([u, v], -1)[:, None, :], K, d, criteria=EXACT).reshape(-1, 2)
    np.testing.assert_allclose(normalised(camera, u, v), opencv, atol=1e-9)


def test_from_opencv_fisheye_undistorts_as_cv2_fisheye():
    camera = tofd.Intrinsics.from_opencv(K, FISHEYE, 640, 576, fisheye=True)
    assert camera.distortion_model == "equidistant"
    u, v = pixels()
    opencv = cv2.fisheye.undistortPoints(np.stack([u, v], -1)[:, None, :], K, FISHEYE,
                                         criteria=EXACT).reshape(-1, 2)
    np.testing.assert_allclose(normalised(camera, u, v), opencv, atol=1e-9)


def test_from_opencv_zero_or_no_distortion_is_a_pinhole_and_bad_input_is_named():
    assert tofd.Intrinsics.from_opencv(K, None, 640, 576).is_pinhole
    assert tofd.Intrinsics.from_opencv(K, np.zeros((1, 5)), 640, 576).is_pinhole
    with pytest.raises(ValueError, match="camera_matrix"):
        tofd.Intrinsics.from_opencv(K[:2], PLUMB_BOB, 640, 576)
    with pytest.raises(ValueError, match="no skew"):
        tofd.Intrinsics.from_opencv(K + [[0, 0.5, 0], [0, 0, 0], [0, 0, 0]], PLUMB_BOB, 640, 576)
    with pytest.raises(ValueError, match="thin-prism"):
        tofd.Intrinsics.from_opencv(K, np.r_[PLUMB_BOB, 0, 0, 0, 0.01, 0, 0, 0], 640, 576)
    with pytest.raises(ValueError, match="dist_coeffs"):
        tofd.Intrinsics.from_opencv(K, [0.1, np.nan, 0, 0, 0], 640, 576)


def test_from_camera_info_takes_messages_dicts_and_yaml_alike():
    camera = tofd.Intrinsics.from_opencv(K, PLUMB_BOB, 640, 576)
    ros2 = {"width": 640, "height": 576, "k": K.ravel().tolist(), "d": PLUMB_BOB.tolist(),
            "distortion_model": "plumb_bob"}
    ros1 = SimpleNamespace(width=640, height=576, K=tuple(K.ravel()), D=tuple(PLUMB_BOB), distortion_model="plumb_bob")
    yaml = {"image_width": 640, "image_height": 576,
            "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
            "distortion_model": "plumb_bob", "distortion_coefficients": {"rows": 1, "cols": 5, "data": list(PLUMB_BOB)}}
    assert tofd.Intrinsics.from_camera_info(ros2) == tofd.Intrinsics.from_camera_info(ros1) == camera
    assert tofd.Intrinsics.from_camera_info(yaml) == camera
    assert tofd.Intrinsics.from_camera_info({**ros2, "d": [0.0] * 5}).is_pinhole
    with pytest.raises(ValueError, match="distortion_model 'fov'"):
        tofd.Intrinsics.from_camera_info({**ros2, "distortion_model": "fov"})
    with pytest.raises(ValueError, match="no field k or K"):
        tofd.Intrinsics.from_camera_info({key: v for key, v in ros2.items() if key != "k"})
    with pytest.raises(ValueError, match="takes 5 coefficients"):
        tofd.Intrinsics.from_camera_info({**ros2, "d": [*PLUMB_BOB, 0.3]})


def test_feature_config_takes_numpy_scalars_as_the_numbers_they_equal():
    config = tofd.FeatureConfig(tuning_frequency_per_m=np.float32(30), grid_size=np.int64(64),
                                damping=np.float64(0.01))
    assert config == tofd.FeatureConfig() and hash(config) == hash(tofd.FeatureConfig())
    assert type(config.grid_size) is int and type(config.tuning_frequency_per_m) is float
    with pytest.raises(ValueError, match="grid_size"):
        tofd.FeatureConfig(grid_size=np.float64(64))
    with pytest.raises(ValueError, match="damping"):
        tofd.FeatureConfig(damping=np.bool_(True))
