"""[camera] and --camera/--serial/--playback: the kind, the vendors' serials and stream modes, checked once."""

import subprocess
import sys
from pathlib import Path

import pytest

from tofd.config import ConfigError, config_from_dict
from tofd.drivers.cameras import CameraRequest, StreamMode

ROOT = Path(__file__).resolve().parents[2]


def test_an_sdk_camera_section_becomes_its_request():
    cfg = config_from_dict({"camera": {"kind": "k4a", "serial": "000123456789", "width": 640, "height": 576,
                                       "fps": 30, "depth_mode": "NFOV_UNBINNED", "exposure_us": 1250}})
    request = cfg.camera.request()
    assert request == CameraRequest(kind="k4a", serial="000123456789", mode=StreamMode(640, 576, 30, "NFOV_UNBINNED"),
                                    settings={"exposure_us": 1250.0})
    assert request.mode.describe() == "640x576, 30 fps, NFOV_UNBINNED"
    assert config_from_dict({"camera": {"kind": "realsense"}}).camera.request().mode.describe() == \
        "the device's default"


@pytest.mark.parametrize(("camera", "message"), [
    ({"kind": "kinect"}, "camera.kind: 'kinect' is not one of sr3000, realsense, orbbec, k4a"),
    ({"serial": "000123456789"}, "camera.serial: '000123456789' is not 8 hex digits"),
    ({"kind": "orbbec", "serial": "AY 12"}, "camera.serial: 'AY 12' is not a camera serial number"),
    ({"width": 640}, "camera.width: the SR3000 camera has a fixed mode and no playback"),
    ({"kind": "realsense", "fps": 5000}, "camera.fps: 5000 is not in 0..1000"),
    ({"kind": "realsense", "laser_power": -2.0}, "camera.laser_power: -2.0 is not -1"),
])
def test_a_wrong_camera_section_names_its_key(camera, message):
    with pytest.raises(ConfigError) as info:
        config_from_dict({"camera": camera})
    assert str(info.value).startswith(message)


@pytest.mark.parametrize(("args", "message"), [
    (["--serial", "000123456789"], "tofd run: --serial: '000123456789' is not 8 hex digits"),
    (["--camera", "k4a", "--playback", "missing.mkv"], "tofd run: --playback: missing.mkv is not a file"),
    (["--playback", "README.md"], "tofd run: --playback: the SR3000 camera has a fixed mode and no playback"),
])
def test_camera_options_are_checked_with_the_kind_in_one_line_exit_2(args, message):
    proc = subprocess.run([sys.executable, "-m", "tofd", "run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, stdin=subprocess.DEVNULL)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith(message) and proc.stderr.count("\n") == 1, proc.stderr
