"""The Orbbec backend through the real Orbbec SDK (its C library from the pyorbbecsdk2 wheel), no camera needed: a
bag the SDK's RecordDevice wrote, played by the SDK's PlaybackDevice in real time as the device, through the same
code a live camera runs: the lens from the device's profile with its distortion, the sphere within millimetres,
the device's frame numbers and timestamps, its exposure, gain and laser power, a paused playback as a stalled
camera, clear errors."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import threading

import numpy as np
import pytest

from tests.commands.test_cli import HANG_GUARD_S, tofd
from tofd.drivers.cameras import CameraRequest, SdkMissing, StreamMode, backend
from tofd.drivers.orbbec import sdk
from tofd.drivers.orbbec.camera import (
    BACKEND,
    PROPERTY_DEPTH_AUTO_EXPOSURE,
    PROPERTY_DEPTH_EXPOSURE,
    PROPERTY_DEPTH_GAIN,
    PROPERTY_LASER_POWER_LEVEL,
)
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.source import DriverError
from tofd_testing.bag_scenes import K4A_LIKE, Scene, depth_units, render, sphere_errors
from tofd_testing.orbbec_bag_helpers import T0_US, write_orbbec_bag
from tofd_testing.rrd_helpers import live_recording
from tofd_testing.vendor_bag_helpers import assert_on_sphere, logged_foreground, pinhole_errors

K = (K4A_LIKE.fx, K4A_LIKE.fy, K4A_LIKE.cx, K4A_LIKE.cy)
k1, k2, p1, p2, k3, k4, k5, k6 = K4A_LIKE.distortion
SDK_ORDER = (k1, k2, k3, k4, k5, k6, p1, p2)
N_FRAMES = 40
SETTINGS = {PROPERTY_DEPTH_AUTO_EXPOSURE: struct.pack("<i", 0), PROPERTY_DEPTH_EXPOSURE: struct.pack("<i", 1700),
            PROPERTY_DEPTH_GAIN: struct.pack("<i", 16), PROPERTY_LASER_POWER_LEVEL: struct.pack("<i", 3)}
"""The device's exposure, gain and laser power as the recording states them (OBPropertyID -> value bytes)."""


@pytest.fixture(scope="module")
def femto_bag(tmp_path_factory):
    """40 frames of the sphere through a Femto-like Brown-Conrady K6 lens, recorded by the SDK (then a lead-in)."""
    z, infrared, _ = render(K4A_LIKE, Scene())
    depth = depth_units(z, 1e-3)
    ir = np.clip(infrared * 60000, 0, 65535).astype(np.uint16)
    path = tmp_path_factory.mktemp("orbbec") / "femto.bag"
    return write_orbbec_bag(path, [depth] * N_FRAMES, [ir] * N_FRAMES, K, SDK_ORDER, properties=SETTINGS)


def playback(bag, **kwargs) -> CameraRequest:
    return CameraRequest(kind="orbbec", playback=bag, **kwargs)


def test_the_registry_finds_the_orbbec_backend():
    assert backend("orbbec") is BACKEND and BACKEND.extra == "orbbec"
    assert BACKEND.list_cameras() == []  # no camera attached here: the SDK sees none, and says so without error


def test_an_sdk_recording_played_by_the_sdk_comes_back_on_the_sphere(femto_bag):
    camera = BACKEND.open(playback(femto_bag))
    with camera:
        frames = list(camera)
        counters = dict(camera.counters)
    numbers = [f.frame_counter for f in frames]
    # the lead-in 6 may be lost (see the helper); the SDK plays in real time, so a loaded machine may miss frames
    assert numbers == sorted(set(numbers)) and set(numbers) <= set(range(6, 7 + N_FRAMES)), numbers
    assert numbers[-1] == 6 + N_FRAMES and len(numbers) >= N_FRAMES // 2, numbers
    assert counters["frames"] == len(frames), counters
    # the lead-in pair may come apart in the SDK's recording (its depth image without its infrared): then it is the
    # one unpaired range, and frame 6 is not delivered
    unpaired = counters.get("unpaired_range", 0)
    assert unpaired == 0 or (unpaired == 1 and 6 not in numbers), counters
    frames = [f for f in frames if f.frame_counter >= 7]
    assert [f.timestamp_us for f in frames] == [T0_US + round((f.frame_counter - 7) * 1e6 / 30) for f in frames]
    first = frames[0]
    assert (first.device.backend, first.device.model, first.device.serial, first.device.firmware) == (
        "orbbec", "Femto Bolt", "CL8F12300AB", "1.0.9")
    lens = first.intrinsics
    assert lens.distortion_model == "rational_polynomial" and lens.shape == (288, 320)
    np.testing.assert_allclose(lens.distortion, K4A_LIKE.distortion, rtol=1e-6, atol=1e-9)  # float32 in the file
    assert first.sensor.depth_unit_m == 1e-3 and first.sensor.amplitude == "ir"
    assert first.sensor.settings["stream"] == "320x288 @ 30 fps Y16"
    assert {k: first.sensor.settings[k] for k in ("depth_auto_exposure", "depth_exposure_us", "depth_gain",
                                                  "laser_power_level")} == {
        "depth_auto_exposure": "False", "depth_exposure_us": "1700", "depth_gain": "16", "laser_power_level": "3"}
    z, infrared, sphere = render(K4A_LIKE, Scene())
    np.testing.assert_array_equal(first.amplitude, np.clip(infrared * 60000, 0, 65535).astype(np.uint16))
    errors = sphere_errors(lens.backproject(first.range_m)[sphere], Scene())
    assert np.median(errors) <= 1e-3 and np.percentile(errors, 90) <= 2e-3
    assert pinhole_errors(K4A_LIKE, Scene()) > 10e-3  # ignoring the lens would put it centimetres off
    assert np.array_equal(np.isnan(first.range_m), np.isnan(z))


def test_a_paused_playback_is_a_stalled_camera_that_comes_back(femto_bag):
    """The SDK's playback paused mid-stream: waits time out, one stall is reported, frames resume in order."""
    camera = BACKEND.open(playback(femto_bag, read_timeout_s=0.1, stall_report_s=0.4))
    with camera:
        frames = iter(camera)
        before = next(frames).frame_counter
        camera.pause_playback()
        resumer = threading.Timer(1.5, camera.resume_playback)
        resumer.start()
        rest = [f.frame_counter for f in frames]
        resumer.join()
        counters = dict(camera.counters)
    assert counters["stall"] == 1 and counters["timeout"] >= 4
    assert before < rest[0] and rest == sorted(set(rest)) and rest[-1] == 6 + N_FRAMES
    assert len(rest) >= N_FRAMES - 3  # the SDK may drop the frame in flight when it pauses


def test_a_stream_mode_the_device_lacks_lists_what_it_offers(femto_bag):
    with pytest.raises(DriverError, match=r"no depth stream of 640x576, 15 fps; it offers: 320x288 @ 30 fps Y16"):
        BACKEND.open(playback(femto_bag, mode=StreamMode(640, 576, 15)))
    with pytest.raises(DriverError, match="depth_mode 'NFOV_UNBINNED'"):
        BACKEND.open(playback(femto_bag, mode=StreamMode(depth_mode="NFOV_UNBINNED")))


def test_settings_the_device_cannot_take_are_refused_by_name(femto_bag):
    with pytest.raises(DriverError, match=r"unknown setting\(s\) gain_db"):
        BACKEND.open(playback(femto_bag, settings={"gain_db": 3}))
    with pytest.raises(DriverError, match="cannot set property 2016.*exposure_us"):
        BACKEND.open(playback(femto_bag, settings={"exposure_us": 1500}))  # a playback device's are read-only


def test_a_file_the_sdk_cannot_play_names_it(tmp_path):
    bad = tmp_path / "notes.bag"
    bad.write_text("not a bag")
    with pytest.raises(DriverError, match=f"{bad}: the Orbbec SDK cannot play it"):
        BACKEND.open(playback(bad))


def test_no_attached_camera_is_a_clear_error():
    with pytest.raises(DriverError, match="no Orbbec camera is attached"):
        BACKEND.open(CameraRequest(kind="orbbec"))


def test_a_missing_sdk_names_the_extra(monkeypatch):
    monkeypatch.setattr(sdk, "_loaded", None)
    monkeypatch.setattr(sdk, "DISTRIBUTION", "pyorbbecsdk2-absent")
    with pytest.raises(SdkMissing, match=r"pip install 'tofd\[orbbec\]'") as caught:
        BACKEND.list_cameras()
    assert caught.value.extra == "orbbec" and "pyorbbecsdk2-absent is not installed" in str(caught.value)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a live segment has none
def test_tofd_run_on_an_sdk_recording_puts_the_foreground_on_the_sphere(femto_bag, tmp_path):
    """The done-when: `tofd run --camera orbbec --playback` on a bag the SDK's RecordDevice wrote."""
    rrd, summary = tmp_path / "orbbec.rrd", tmp_path / "summary.json"
    env = {k: v for k, v in os.environ.items() if k != "RERUN"} | {"RUST_LOG": "error"}
    proc = subprocess.run([sys.executable, "-m", "tofd", "run", "--camera", "orbbec", "--playback", str(femto_bag),
                           "--frames", str(N_FRAMES), "--rerun", f"save:{rrd}", "--health-port", "0", "--summary",
                           str(summary)], capture_output=True, text=True, timeout=HANG_GUARD_S, env=env)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(summary.read_text())
    assert report["error"] is None and report["consistent"] and report["shutdown"]["reason"] == "end", report
    # real time: frames the SDK played while tofd was busy are gaps in the ledger; the SDK's playback may split
    # one frame pair (counted as unpaired) and lose the lead-in's depth image
    lost = sum(gap["next_counter"] - gap["after_counter"] - 1 for gap in report["gaps"])
    assert N_FRAMES - 2 <= report["frames_in"] + lost and report["frames_in"] <= N_FRAMES
    _, _, sphere = render(K4A_LIKE, Scene())
    foreground = logged_foreground(live_recording(rrd))
    assert 1 <= len(foreground) == report["viewer"]["frames"]  # live: a busy machine's viewer drops frames
    for points in foreground:
        assert_on_sphere(points, Scene(), int(sphere.sum()))


def test_tofd_record_keeps_the_orbbec_lens_and_numbers(femto_bag, tmp_path):
    out = tmp_path / "femto.mcap"
    proc = tofd("record", "--camera", "orbbec", "--playback", str(femto_bag), str(out))
    assert proc.returncode == 0, proc.stderr
    frames = list(iter_frames(out))
    numbers = [f.frame_counter for f in frames]
    assert numbers == sorted(set(numbers)) and numbers[-1] == 6 + N_FRAMES and len(numbers) >= N_FRAMES - 2
    lens = frames[-1].intrinsics
    assert lens.distortion_model == "rational_polynomial"
    np.testing.assert_allclose(lens.distortion, K4A_LIKE.distortion, rtol=1e-6, atol=1e-9)
    _, _, sphere = render(K4A_LIKE, Scene())
    errors = sphere_errors(lens.backproject(frames[-1].range_m)[sphere], Scene())
    assert np.median(errors) <= 1e-3 and np.percentile(errors, 90) <= 2e-3


@pytest.mark.device
def test_an_attached_orbbec_camera_streams_with_its_own_lens():
    """For people who own one (Femto Bolt / Mega, Gemini): `pytest -m device tests/drivers/test_orbbec_camera.py`."""
    cameras = BACKEND.list_cameras()
    if not cameras:
        pytest.skip("no Orbbec camera attached")
    camera = BACKEND.open(CameraRequest(kind="orbbec", serial=cameras[0].serial))
    with camera:
        frames = [frame for frame, _ in zip(camera, range(30), strict=False)]
    assert frames[0].device.serial == cameras[0].serial and frames[0].intrinsics is not None
    numbers, stamps = [f.frame_counter for f in frames], [f.timestamp_us for f in frames]
    assert numbers == sorted(set(numbers)) and stamps == sorted(set(stamps))
    assert frames[-1].sensor.depth_unit_m > 0 and "stream" in frames[-1].sensor.settings
    assert np.isfinite(frames[-1].range_m).mean() > 0.1  # a camera looking at anything returns depth somewhere
