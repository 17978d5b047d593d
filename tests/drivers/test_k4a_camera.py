"""The live Azure Kinect backend (tofd.drivers.k4a.camera) through Microsoft's libk4a / libk4arecord: recordings
written by libk4arecord played by its k4a_playback_* as the device, the same k4a_capture_t objects a camera gives,
through the live conversion; `tofd run --camera k4a --playback FILE` end to end."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.drivers.test_k4a import RAW, SERIAL, mode_size, render_scene, tofd
from tofd.drivers.cameras import CameraRequest, StreamMode, backend
from tofd.drivers.k4a.lens import depth_lens
from tofd.drivers.k4a.mkv import K4aRecordingSource
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.source import DriverError
from tofd_testing.k4a_helpers import K4A
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config
from tofd_testing.rrd_helpers import foreground_clouds, live_recording

RADIUS = 0.10


@pytest.fixture(scope="module")
def k4a() -> K4A:
    from tofd_testing.k4a_helpers import k4a_libraries

    return k4a_libraries()


def sphere_recording(k4a: K4A, path: Path, mode: str, frames: int, fps: int = 30) -> tuple[Path, np.ndarray, list]:
    """A libk4arecord recording (with IMU and colour tracks) of a sphere 45 degrees off axis in the distorted
    corner, `frames` captures at `fps`; and the sphere's centre and the capture times."""
    depth, ir, centre = render_scene(mode, (130, 120) if mode == "WFOV_2X2BINNED" else (100, 90), 0.65, RADIUS)
    period = 1_000_000 // fps
    stamps = [2_000_000 + period * k for k in range(frames)]
    k4a.write_recording(path, mode, [depth] * frames, [ir] * frames, stamps, fps=fps, calibration=RAW, serial=SERIAL,
                        imu=True, colour_us=[t + period // 3 for t in stamps])
    return path, centre, stamps


def open_playback(path: Path, **mode: object) -> object:
    return backend("k4a").open(CameraRequest(kind="k4a", playback=path, mode=StreamMode(**mode)))  # type: ignore[arg-type]


def test_playback_gives_the_sphere_through_the_devices_lens_in_real_time(k4a, tmp_path):
    mode = "NFOV_UNBINNED"
    path, centre, stamps = sphere_recording(k4a, tmp_path / "sphere.mkv", mode, 6)
    camera = open_playback(path)
    lens = depth_lens(RAW, mode)
    assert camera.intrinsics == lens.intrinsics and camera.intrinsics.distortion_model == "rational_polynomial"
    assert (camera.device_info.serial, camera.device_info.backend, camera.device_info.model) == \
        (SERIAL, "k4a", "Azure Kinect")
    assert camera.sensor.depth_unit_m == 1e-3 and camera.sensor.amplitude == "ir"
    assert camera.sensor.settings["K4A_DEPTH_MODE"] == mode
    started = time.monotonic()
    with camera:
        frames = list(camera)
    elapsed = time.monotonic() - started
    assert [f.timestamp_us for f in frames] == stamps and [f.frame_counter for f in frames] == list(range(6))
    assert elapsed >= 0.9 * (stamps[-1] - stamps[0]) / 1e6  # played at the pace of the device timestamps
    assert mode_size(mode) == frames[0].range_m.shape
    # the sphere through the device's lens: within the millimetre steps of the depth image
    xyz = frames[-1].intrinsics.backproject(frames[-1].range_m)
    on = np.isfinite(frames[-1].range_m) & (np.linalg.norm(xyz - centre, axis=-1) < RADIUS + 0.02)
    off = np.abs(np.linalg.norm(xyz[on] - centre, axis=1) - RADIUS)
    assert on.sum() > 2000 and np.median(off) < 0.001 and np.percentile(off, 99) < 0.003, \
        (np.median(off), np.percentile(off, 99))
    # the same pixels as the .mkv reader gives of the same file
    recorded = list(K4aRecordingSource(path))
    np.testing.assert_allclose(frames[-1].range_m, recorded[-1].range_m, rtol=1e-5, equal_nan=True)
    np.testing.assert_array_equal(frames[-1].amplitude, recorded[-1].amplitude)


def test_the_stream_mode_is_checked_against_the_recording_and_the_device(k4a, tmp_path):
    path, _, _ = sphere_recording(k4a, tmp_path / "s.mkv", "NFOV_2X2BINNED", 2, fps=15)
    with open_playback(path, depth_mode="NFOV_2X2BINNED", fps=15) as camera:
        assert len(list(camera)) == 2
    with pytest.raises(DriverError, match="recorded in NFOV_2X2BINNED at 15 fps, not WFOV_2X2BINNED at 30 fps"):
        open_playback(path, depth_mode="WFOV_2X2BINNED")
    with pytest.raises(DriverError, match="30 fps is not offered in WFOV_UNBINNED; the Azure Kinect offers"):
        open_playback(path, depth_mode="WFOV_UNBINNED", fps=30)
    with pytest.raises(DriverError, match="no depth mode makes 640x480 images"):
        open_playback(path, width=640, height=480)
    with pytest.raises(DriverError, match="has no exposure_us setting"):
        backend("k4a").open(CameraRequest(kind="k4a", playback=path, settings={"exposure_us": 500}))
    if not backend("k4a").list_cameras():  # no Azure Kinect attached here
        with pytest.raises(DriverError, match="no Azure Kinect"):
            backend("k4a").open(CameraRequest(kind="k4a"))


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a live segment has none
def test_tofd_run_on_a_playback_puts_the_foreground_on_the_sphere(k4a, tmp_path):
    mode = "WFOV_2X2BINNED"
    path, centre, _ = sphere_recording(k4a, tmp_path / "wide.mkv", mode, 12, fps=5)
    rrd, summary = tmp_path / "run.rrd", tmp_path / "s.json"
    proc = tofd("run", "--camera", "k4a", "--playback", path, "--frames", 12, "--rerun", f"save:{rrd}",
                "--health-port", 0, "--summary", summary,
                "--config", bundled_config(tmp_path / "tofd.toml", pipeline=PATIENT_VIEWER))
    assert proc.returncode == 0, proc.stderr
    s = json.loads(summary.read_text())
    assert s["frames_in"] == s["frames_out"] + s["frames_dropped"] and s["frames_out"] >= 1, s
    clouds = foreground_clouds(live_recording(rrd))
    assert clouds and all(len(c) > 300 for c in clouds)
    for points in clouds:
        off = np.abs(np.linalg.norm(points - centre, axis=1) - RADIUS)
        assert np.median(off) < 0.002 and np.percentile(off, 90) < 0.005, (np.median(off), np.percentile(off, 90))


def test_a_recording_that_stops_sending_stalls_and_leaves_a_gap(k4a, tmp_path):
    """Captures 2.5 s apart in the middle of a recording: the played device sends nothing meanwhile, so the shared
    loop times out, reports one stall, and the next frame's counter jumps by the frames the device did not send."""
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    plane = np.full((h, w), 1000, np.uint16)
    period = 1_000_000 // 30
    stamps = [1_000_000 + period * k for k in range(3)] + [3_600_000 + period * k for k in range(2)]
    path = k4a.write_recording(tmp_path / "gap.mkv", mode, [plane] * 5, [plane] * 5, stamps, calibration=RAW,
                               serial=SERIAL, imu=True)
    camera = backend("k4a").open(CameraRequest(kind="k4a", playback=path, read_timeout_s=0.2, stall_report_s=1.0))
    with camera:
        frames = list(camera)
    gap = round((stamps[3] - stamps[0]) / period)
    assert [f.frame_counter for f in frames] == [0, 1, 2, gap, gap + 1]
    assert camera.counters["stall"] == 1 and camera.counters["timeout"] >= 5, dict(camera.counters)


def test_tofd_record_keeps_the_devices_lens_and_a_missing_sdk_names_the_extra(k4a, tmp_path):
    path, _, stamps = sphere_recording(k4a, tmp_path / "s.mkv", "NFOV_2X2BINNED", 5, fps=15)
    out = tmp_path / "rec.mcap"
    proc = tofd("record", "--camera", "k4a", "--playback", path, "--frames", 5, out)
    assert proc.returncode == 0, proc.stderr
    info = read_recording_info(out)
    assert info.intrinsics == depth_lens(RAW, "NFOV_2X2BINNED").intrinsics and info.registers is None
    assert (info.device.backend, info.device.serial) == ("k4a", SERIAL) and info.sensor.depth_unit_m == 1e-3
    assert [f.timestamp_us for f in iter_frames(out)] == stamps
    # a pyk4a package without pyk4a-bundle's libraries beside it (another build of pyk4a): one line, exit 2
    fake = tmp_path / "site" / "pyk4a"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    env = {**os.environ, "PYTHONPATH": str(fake.parent)}
    proc = subprocess.run([sys.executable, "-m", "tofd", "run", "--camera", "k4a", "--frames", "1"],
                          capture_output=True, text=True, timeout=300, env=env)
    err = proc.stderr.strip()
    assert proc.returncode == 2 and len(err.splitlines()) == 1 and "pip install 'tofd[k4a]'" in err, err
    assert "no libk4a / libk4arecord" in err


@pytest.mark.device
def test_an_attached_azure_kinect_streams_through_its_own_lens():
    """On a machine with an Azure Kinect: WFOV_2X2BINNED at 15 fps, ten frames with increasing device times, the
    device's own Brown-Conrady lens, returns in most of the image circle."""
    if not backend("k4a").list_cameras():
        pytest.skip("no Azure Kinect attached")
    camera = backend("k4a").open(CameraRequest(kind="k4a", mode=StreamMode(depth_mode="WFOV_2X2BINNED", fps=15)))
    with camera:
        frames = [f for _, f in zip(range(10), camera, strict=False)]
    assert len(frames) == 10 and frames[0].range_m.shape == (512, 512)
    assert camera.intrinsics.distortion_model == "rational_polynomial" and camera.device_info.serial
    assert all(b.timestamp_us > a.timestamp_us and b.frame_counter > a.frame_counter
               for a, b in zip(frames, frames[1:], strict=False))
    assert np.isfinite(frames[-1].range_m).mean() > 0.3
