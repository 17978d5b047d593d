"""The live RealSense backend through librealsense's own device code, without a camera: a recording written by
librealsense 2.59's recorder (a sphere moving through a Brown-Conrady lens, 640x480) played by the SDK's playback
device in real time through rs.pipeline, as `tofd run --camera realsense --playback` and in process (paused and
resumed for a device that stops sending); an rs.software_device's depth sensor fed frame by frame with a known
surface for the conversion; a real camera behind the `device` marker."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading

import numpy as np
import pytest

from tests.commands.test_cli import HANG_GUARD_S, tofd
from tofd.drivers.cameras import CameraRequest, StreamMode, backend
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.live import SdkCamera
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.source import DriverError
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.pixels import CLOUD_POINTS
from tofd_testing.bag_scenes import RS_LIKE, RS_SCENE, Scene, depth_units, render, sphere_errors
from tofd_testing.chaos_helpers import free_port, metric, metrics, wait_for
from tofd_testing.chaos_helpers import tofd as chaos_tofd
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config
from tofd_testing.rrd_helpers import live_recording, read_entities
from tofd_testing.vendor_bag_helpers import pinhole_errors, realsense_env, record_realsense

RS_640 = Intrinsics(640, 480, 500.0, 502.5, 323.3, 236.6, "plumb_bob", (-0.25, 0.09, 0.0012, -0.0009, -0.012))
"""A RealSense depth stream at 640x480 with a wide-angle Brown-Conrady lens."""
N_FRAMES = 60
FIRST = 100
UNITS_M = 1e-4  # not the D400's 1 mm, so that the unit must be read from the device
SCENES = [Scene(centre=(0.22 + 0.06 * t, 0.16, 0.6 + 0.1 * t)) for t in np.linspace(0, 1, N_FRAMES)]
"""The sphere moves 6 cm across and 10 cm away over the recording, in the distorted corner."""


@pytest.fixture(scope="module")
def recording(tmp_path_factory, vendor_cache_dir):
    env = realsense_env("current", vendor_cache_dir)
    return record_realsense(tmp_path_factory.mktemp("rs") / "moving.db3", env, RS_640, SCENES, UNITS_M,
                            first_number=FIRST)


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory, vendor_cache_dir):
    """Ten seconds of a still sphere at 256x192: long enough to stop a run in the middle."""
    env = realsense_env("current", vendor_cache_dir)
    return record_realsense(tmp_path_factory.mktemp("rs") / "long.db3", env, RS_LIKE, RS_SCENE, UNITS_M, 300)


def playback(path, **fields) -> SdkCamera:
    camera = backend("realsense").open(CameraRequest("realsense", playback=path, **fields))
    assert isinstance(camera, SdkCamera)
    return camera


def on_sphere(points: np.ndarray, scene: Scene, pixels: int) -> tuple[float, float]:
    """(median, 90th percentile) distance of the points from the scene's sphere, metres; much of it covered."""
    errors = sphere_errors(points, scene)
    assert len(points) >= 0.3 * pixels, (len(points), pixels)
    return float(np.median(errors)), float(np.percentile(errors, 90))


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a live segment has none
def test_run_on_the_playback_device_puts_the_foreground_on_the_moving_sphere(recording, tmp_path):
    rrd, summary_path = tmp_path / "x.rrd", tmp_path / "s.json"
    config = bundled_config(tmp_path / "patient.toml", pipeline=PATIENT_VIEWER)
    env = {k: v for k, v in os.environ.items() if k != "RERUN"} | {"RUST_LOG": "error"}
    proc = subprocess.run([sys.executable, "-m", "tofd", "run", "--camera", "realsense", "--playback", str(recording),
                           "--frames", "40", "--rerun", f"save:{rrd}", "--health-port", "0", "--summary",
                           str(summary_path), "--config", str(config)], capture_output=True, text=True,
                          timeout=HANG_GUARD_S, env=env)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(summary_path.read_text())
    assert summary["error"] is None and summary["consistent"] and summary["frames_in"] == 40, summary
    assert summary["frames_in"] == summary["frames_out"] + summary["frames_dropped"]
    assert summary["viewer"]["exit"] == "clean"
    _, table = read_entities(live_recording(rrd))[bp.FOREGROUND]
    counters = table.column("frame").to_pylist()
    # real time on a loaded machine: the SDK may skip frames, so the 40 taken reach further into the recording, and
    # the pipeline and the best-effort viewer drop what they cannot take in time (a quiet machine logs about 30)
    assert 1 <= len(counters) == summary["viewer"]["frames"], (counters, summary["viewer"])
    assert all(FIRST <= c < FIRST + N_FRAMES for c in counters), counters
    column = table.column("Points3D:positions")
    for row, counter in enumerate(counters):
        scene = SCENES[counter - FIRST]
        points = np.asarray(column[row].as_py(), np.float64).reshape(-1, 3)
        # the viewer logs an even subsample of at most CLOUD_POINTS of a large foreground
        median, p90 = on_sphere(points, scene, min(int(render(RS_640, scene)[2].sum()), CLOUD_POINTS))
        assert median <= 2e-3 and p90 <= 5e-3, (counter, median, p90)
        assert pinhole_errors(RS_640, scene) > 2e-3  # without the lens the same check would fail
        print(f"frame {counter}: {len(points)} points, median {median * 1e3:.3f} mm, p90 {p90 * 1e3:.3f} mm")


@pytest.mark.slow
def test_sigterm_during_a_playback_drains_and_exits_0_with_its_summary(long_recording, tmp_path):
    summary_path, port = tmp_path / "s.json", free_port()
    proc = chaos_tofd("run", "--camera", "realsense", "--playback", long_recording, "--rerun", "none",
                      "--health-port", port, "--summary", summary_path)
    try:
        assert wait_for(lambda: metric(metrics(port), "tofd_frames_out_total") >= 5 or proc.poll() is not None,
                        HANG_GUARD_S)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads(summary_path.read_text())
    assert summary["shutdown"]["reason"] == "SIGTERM" and summary["error"] is None, summary
    assert summary["consistent"] and summary["frames_pending"] == 0 and summary["frames_out"] >= 5
    assert summary["frames_in"] < 300  # stopped in the middle of the ten seconds


def test_the_playback_device_gives_the_devices_lens_units_numbers_and_times(recording):
    camera = playback(recording)
    with camera:
        frames = list(camera)
    assert camera.intrinsics is not None and camera.sensor is not None
    assert camera.intrinsics.distortion_model == "plumb_bob"
    np.testing.assert_allclose(camera.intrinsics.distortion, RS_640.distortion, rtol=1e-6, atol=1e-9)
    assert (camera.intrinsics.fx, camera.intrinsics.cy) == pytest.approx((RS_640.fx, RS_640.cy), rel=1e-6)
    assert camera.sensor.depth_unit_m == pytest.approx(UNITS_M, rel=1e-6)
    assert (camera.sensor.amplitude, camera.sensor.amplitude_full_scale) == ("ir", 255.0)
    assert camera.sensor.settings["source"] == "playback"
    assert camera.sensor.settings["depth_stream"] == "640x480 @ 30 fps Z16"
    device = frames[0].device
    assert (device.backend, device.model, device.serial, device.firmware) == (
        "realsense", "Software RealSense", "0123456789", "5.16.0.1")
    numbers = [f.frame_counter for f in frames]
    assert numbers == sorted(set(numbers)) and numbers[0] == FIRST and numbers[-1] == FIRST + N_FRAMES - 1
    assert len(numbers) >= N_FRAMES - 2, numbers  # real time: a loaded machine may miss a frame, never reorder
    for frame in frames[:: max(1, len(frames) // 4)]:
        i = frame.frame_counter - FIRST
        assert abs(frame.timestamp_us - (1e6 + i * 1e6 / 30)) <= 1
        z, infrared, sphere = render(RS_640, SCENES[i])
        expected = RS_640.radial_from_z(np.where(depth_units(z, UNITS_M) > 0, z, np.nan))
        assert np.array_equal(np.isnan(frame.range_m), np.isnan(expected))
        assert np.nanmax(np.abs(frame.range_m - expected)) <= UNITS_M  # within the depth unit
        assert np.array_equal(frame.amplitude, np.clip(infrared * 1000, 0, 255).astype(np.uint8))
        median, p90 = on_sphere(frame.intrinsics.backproject(frame.range_m)[sphere], SCENES[i], int(sphere.sum()))
        assert median <= 1e-3 and p90 <= 2e-3, (median, p90)


def test_a_paused_playback_is_a_stall_then_streams_on(recording):
    """Paused for 3 stall periods after the 5th frame: one stall reported, waits timed out, no crash, and the
    frames after the pause come in order."""
    camera = playback(recording, read_timeout_s=0.1, stall_report_s=0.5)
    numbers = []
    with camera:
        for frame in camera:
            numbers.append(frame.frame_counter)
            if len(numbers) == 5:
                player = camera.playback  # type: ignore[attr-defined]
                player.pause()
                threading.Timer(1.5, player.resume).start()
    assert camera.counters["stall"] == 1 and camera.counters["timeout"] >= 5, dict(camera.counters)
    assert numbers == sorted(set(numbers)) and numbers[-1] == FIRST + N_FRAMES - 1, numbers
    assert len(numbers) >= N_FRAMES - 2


def test_record_writes_the_camera_into_a_tofd_recording_with_its_lens_and_sensor(recording, tmp_path):
    """`tofd record --camera realsense --playback FILE`: the recording's info carries the device's lens (with its
    distortion), its SensorInfo (depth unit, infrared, streams) and identity; its frames replay in order, on the
    sphere through that lens."""
    out = tmp_path / "rec.mcap"
    proc = tofd("record", "--camera", "realsense", "--playback", str(recording), "--frames", "30", str(out))
    assert proc.returncode == 0, proc.stderr
    info = read_recording_info(out)
    assert info.intrinsics.distortion_model == "plumb_bob"
    np.testing.assert_allclose(info.intrinsics.distortion, RS_640.distortion, rtol=1e-6, atol=1e-9)
    assert info.registers is None and info.sensor is not None
    assert info.sensor.depth_unit_m == pytest.approx(UNITS_M, rel=1e-6) and info.sensor.amplitude == "ir"
    assert info.sensor.settings["depth_stream"] == "640x480 @ 30 fps Z16"
    assert (info.device.backend, info.device.serial) == ("realsense", "0123456789")
    frames = list(iter_frames(out))
    numbers = [f.frame_counter for f in frames]
    assert len(frames) == 30 and numbers == sorted(set(numbers)) and numbers[0] == FIRST, numbers
    assert all(f.sensor == info.sensor and f.intrinsics == info.intrinsics for f in frames)
    last = frames[-1]
    _, _, sphere = render(RS_640, SCENES[last.frame_counter - FIRST])
    median, p90 = on_sphere(last.intrinsics.backproject(last.range_m)[sphere], SCENES[last.frame_counter - FIRST],
                            int(sphere.sum()))
    assert median <= 1e-3 and p90 <= 2e-3, (median, p90)
    info_proc = tofd("info", str(out))
    assert info_proc.returncode == 0 and "damage:     none found" in info_proc.stdout, info_proc.stdout


def test_a_mode_the_recording_does_not_offer_is_refused_naming_what_it_offers(recording):
    with pytest.raises(DriverError, match=r"no depth \+ infrared stream of 848x480, 90 fps; it offers "
                                          r"640x480 @ 30 fps"):
        playback(recording, mode=StreamMode(848, 480, 90))
    with pytest.raises(DriverError, match="no depth modes"):
        playback(recording, mode=StreamMode(depth_mode="NFOV_UNBINNED"))


def software_sensor(rs, lens: Intrinsics, units_m: float):
    """An rs.software_device's depth sensor streaming Z16 depth and Y16 Infrared 1 through `lens`, its Depth Units
    option `units_m`; (device, sensor, [depth profile, infrared profile])."""
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = lens.width, lens.height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = lens.fx, lens.fy, lens.cx, lens.cy
    intrinsics.model, intrinsics.coeffs = rs.distortion.brown_conrady, list(lens.distortion)
    device = rs.software_device()
    sensor = device.add_sensor("Stereo Module")
    profiles = []
    for kind, index, bpp, fmt in ((rs.stream.depth, 0, 2, rs.format.z16), (rs.stream.infrared, 1, 2, rs.format.y16)):
        stream = rs.video_stream()
        stream.type, stream.index, stream.uid = kind, index, index
        stream.width, stream.height, stream.fps, stream.bpp, stream.fmt = lens.width, lens.height, 30, bpp, fmt
        stream.intrinsics = intrinsics
        profiles.append(sensor.add_video_stream(stream))
    sensor.add_read_only_option(rs.option.depth_units, units_m)
    return device, sensor, profiles


def test_the_software_devices_sensor_fed_a_known_surface_converts_through_the_live_code():
    """What the recording does not vary, fed frame by frame to an rs.software_device's depth sensor: a D400's
    1 mm unit, Y16 infrared, a stronger lens, a sphere at the edge of the view; the live camera's own functions
    (its modes, lens, sensor info, capture and conversion) put the range on the sphere within a millimetre."""
    from tofd.drivers.realsense import camera as rs_camera
    from tofd.drivers.realsense.sdk import rs

    lens = Intrinsics(320, 240, 210.0, 211.0, 161.7, 118.2, "plumb_bob", (-0.3, 0.12, -0.0015, 0.001, -0.025))
    units = 1e-3
    _device, sensor, profiles = software_sensor(rs, lens, units)
    (mode,) = rs_camera.offered_modes(sensor)
    assert mode == rs_camera.choose_mode([mode], StreamMode(320, 240, 30), "software device")
    assert mode.infrared_format == "y16"
    camera = rs_camera.RealSenseCamera(CameraRequest("realsense"))
    camera.intrinsics = rs_camera.stream_intrinsics(profiles[0], "software device")
    camera.sensor = rs_camera.sensor_info(sensor, mode, "camera")
    assert camera.intrinsics.distortion_model == "plumb_bob"
    assert (camera.sensor.depth_unit_m, camera.sensor.amplitude_full_scale) == (pytest.approx(units), 65535.0)
    queue = rs.frame_queue(4, keep_frames=True)  # the frames as the sensor sends them (rs.syncer pairs no
    sensor.open(profiles)                       # software frames here: it passes one stream of each pair)
    sensor.start(queue)
    try:
        for i, centre in enumerate([(-0.25, -0.15, 0.7), (0.3, 0.05, 0.8), (-0.22, 0.17, 0.6)]):
            scene = Scene(centre=centre, radius=0.08)
            z, infrared, sphere = render(lens, scene)
            for profile, plane in ((profiles[0], depth_units(z, units)),
                                   (profiles[1], (infrared * 60000).astype(np.uint16))):
                image = rs.software_video_frame()
                image.pixels = np.ascontiguousarray(plane)
                image.bpp, image.stride = 2, lens.width * 2
                image.timestamp, image.domain = 5000.0 + 100 * i, rs.timestamp_domain.hardware_clock
                image.frame_number = 7 + i
                image.profile = profile.as_video_stream_profile()
                sensor.on_video_frame(image)
            depth, infrared_frame = (queue.wait_for_frame(2000) for _ in profiles)
            capture = rs_camera.capture_of(depth.as_depth_frame(), infrared_frame.as_video_frame())
            assert (capture.frame_counter, capture.timestamp_us) == (7 + i, 5_000_000 + 100_000 * i)
            frame = camera.frame(capture)
            assert np.array_equal(frame.amplitude, (infrared * 60000).astype(np.uint16).astype(np.float32))
            median, p90 = on_sphere(frame.intrinsics.backproject(frame.range_m)[sphere], scene, int(sphere.sum()))
            assert median <= 0.5e-3 and p90 <= 1e-3, (i, median, p90)
            print(f"software device frame {i}: median {median * 1e3:.3f} mm, p90 {p90 * 1e3:.3f} mm")
            assert pinhole_errors(lens, scene) > 2e-3, i  # without the lens: 4 times the tolerance and more
    finally:
        sensor.stop()
        sensor.close()


def test_settings_are_set_on_the_depth_sensor_and_read_back_into_the_frames_sensor_info():
    """exposure_us and laser_power set through librealsense's option API on a software sensor with a D400's option
    ranges (manual exposure turns automatic exposure off), read back into SensorInfo.settings; a value outside
    the device's range, or a setting the sensor lacks, is refused naming it."""
    from tofd.drivers.realsense import camera as rs_camera
    from tofd.drivers.realsense.sdk import rs

    _device, sensor, _ = software_sensor(rs, RS_LIKE, 1e-3)
    for option, limits in {"exposure": (1, 165000, 1, 8500), "laser_power": (0, 360, 30, 150),
                           "enable_auto_exposure": (0, 1, 1, 1)}.items():
        option_range = rs.option_range()  # by name: the constructor's step and default came out swapped in 2.59
        option_range.min, option_range.max, option_range.step, option_range.default = limits
        sensor.add_option(getattr(rs.option, option), option_range, True)
    sensor.set_option(rs.option.enable_auto_exposure, 1)
    rs_camera.apply_settings(sensor, {"exposure_us": 1250.0, "laser_power": 90.0}, "software device")
    (mode,) = rs_camera.offered_modes(sensor)
    settings = rs_camera.sensor_info(sensor, mode, "camera").settings
    assert (settings["exposure"], settings["laser_power"], settings["enable_auto_exposure"]) == ("1250", "90", "0")
    with pytest.raises(DriverError, match="software device: laser_power 400 is outside the device's range 0..360"):
        rs_camera.apply_settings(sensor, {"laser_power": 400.0}, "software device")
    with pytest.raises(DriverError, match="software device: laser_power 95: the device refuses it"):
        rs_camera.apply_settings(sensor, {"laser_power": 95.0}, "software device")  # between its 30 mW steps
    with pytest.raises(DriverError, match="software device: the depth sensor has no gain setting"):
        rs_camera.apply_settings(sensor, {"gain": 16.0}, "software device")
    assert sensor.get_option(rs.option.laser_power) == 90.0  # a refused value leaves the setting alone


@pytest.mark.device
def test_a_real_realsense_camera_streams_frames_with_its_lens():
    """For people who own a RealSense: the first attached camera gives frames of its own calibration."""
    cameras = backend("realsense").list_cameras()
    if not cameras:
        pytest.skip("no RealSense camera attached")
    camera = backend("realsense").open(CameraRequest("realsense", serial=cameras[0].serial))
    with camera:
        frames = [frame for frame, _ in zip(camera, range(30), strict=False)]
    assert len(frames) == 30 and frames[0].device.serial == cameras[0].serial
    assert all(f.range_m.shape == camera.intrinsics.shape for f in frames)  # type: ignore[union-attr]
    assert np.isfinite(frames[-1].range_m).mean() > 0.1  # something in front of the camera
