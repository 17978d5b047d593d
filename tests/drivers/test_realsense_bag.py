"""RealSense SDK recordings made at test time by librealsense's own recorder (pyrealsense2 software_device +
rs.recorder): 2.59 writes the ROS 2 .db3 (compressedDepth PNG, depth units in each frame's metadata), 2.56 the
legacy ROS 1 .bag (images with a trailing float32 depth unit). A sphere rendered through a Brown-Conrady lens comes
back from `tofd replay` in 3-D on the sphere; device numbers, times, units and identity come from the file; a
file cut short replays its readable prefix."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.commands.test_cli import one_line_error, tofd
from tofd.drivers.bags.opener import open_bag
from tofd.drivers.bags.realsense import RealSenseSource
from tofd.drivers.opener import identify
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.source import SourceReport
from tofd_testing.bag_scenes import RS_LIKE, RS_SCENE, render
from tofd_testing.vendor_bag_helpers import (
    LEGACY_VERSION,
    assert_on_sphere,
    logged_foreground,
    pinhole_errors,
    realsense_env,
    record_realsense,
    replay_saving_rrd,
)

VERSIONS = {"db3": ("current", 1e-4), "bag": (LEGACY_VERSION, 5e-4)}
"""File kind -> (pyrealsense2 version, depth unit in metres): units other than 1 mm, so that they must be read."""
N_FRAMES = 6


@pytest.fixture(scope="module", params=sorted(VERSIONS))
def recording(request, tmp_path_factory, vendor_cache_dir):
    kind = request.param
    version, units = VERSIONS[kind]
    env = realsense_env(version, vendor_cache_dir)
    path = record_realsense(tmp_path_factory.mktemp(kind) / f"rs.{kind}", env, RS_LIKE, RS_SCENE, units, N_FRAMES)
    return kind, path, units


def test_the_recorder_writes_the_layout_of_its_version(recording):
    kind, path, _ = recording
    assert path.read_bytes().startswith(b"SQLite format 3" if kind == "db3" else b"#ROSBAG V2.0")
    assert identify(path).name == "realsense"


def test_frames_carry_the_device_numbers_times_units_lens_and_identity(recording):
    kind, path, units = recording
    with open_bag(path) as source:
        assert isinstance(source, RealSenseSource)
        frames = list(source)
        assert dict(source.counters) == {} and source.report == SourceReport("end", "", 100 + N_FRAMES - 1)
        assert source.settings["depth_units_m"] == pytest.approx(units, rel=1e-6)
    assert [f.frame_counter for f in frames] == list(range(100, 100 + N_FRAMES))
    expected_us = 1e6 + np.arange(N_FRAMES) * 1e6 / 30  # the device timestamps, in milliseconds in the file
    assert np.abs(np.array([f.timestamp_us for f in frames]) - expected_us).max() <= 1
    intrinsics = frames[0].intrinsics
    assert intrinsics.distortion_model == "plumb_bob"
    np.testing.assert_allclose(intrinsics.distortion, RS_LIKE.distortion, rtol=1e-6, atol=1e-9)  # float32 in the file
    assert (intrinsics.fx, intrinsics.cx) == pytest.approx((RS_LIKE.fx, RS_LIKE.cx), rel=1e-6)
    device = frames[0].device
    assert (device.backend, device.model, device.serial) == ("realsense", "Software RealSense", "0123456789")
    z, infrared, sphere = render(RS_LIKE, RS_SCENE)
    radial = RS_LIKE.radial_from_z(z)
    got = frames[0].range_m
    assert np.array_equal(np.isnan(got), np.isnan(np.where(np.rint(np.nan_to_num(z) / units) > 0, z, np.nan)))
    assert np.nanmax(np.abs(got - radial)) <= units  # within the depth unit
    assert np.array_equal(frames[0].amplitude, np.clip(infrared * 1000, 0, 255).astype(np.uint8))


def test_frames_carry_the_recordings_settings_not_sr3000_registers_through_import(recording, tmp_path):
    """No SR3000 register map: registers None and a SensorInfo from the file (its depth unit, 0 invalid, 8-bit
    infrared, the period of the device timestamps, the streams and options); `tofd import` keeps it in the
    recording's header and in every frame, with the camera's identity."""
    kind, path, units = recording
    with open_bag(path) as source:
        frames = list(source)
    sensor = frames[0].sensor
    assert sensor is not None and all(f.registers is None and f.sensor == sensor for f in frames)
    assert sensor.depth_unit_m == pytest.approx(units, rel=1e-6)
    assert (sensor.invalid_value, sensor.amplitude, sensor.amplitude_full_scale) == (0, "ir", 255.0)
    assert sensor.frame_period_s == pytest.approx(1 / 30, abs=2e-6) and sensor.unambiguous_range_m is None
    assert sensor.settings["format"].startswith("RealSense SDK") and "depth_stream" in sensor.settings
    out = tmp_path / "rs.mcap"
    proc = tofd("import", str(path), str(out))
    assert proc.returncode == 0, proc.stderr
    info = read_recording_info(out)
    assert (info.registers, info.sensor, info.device) == (None, sensor, frames[0].device)
    assert (info.device.model, info.device.serial) == ("Software RealSense", "0123456789")
    replayed = list(iter_frames(out))
    assert [f.frame_counter for f in replayed] == [f.frame_counter for f in frames]
    assert all(f.registers is None and f.sensor == sensor for f in replayed)


@pytest.mark.slow
def test_replay_puts_the_foreground_on_the_sphere_through_the_lens(recording, tmp_path):
    kind, path, _ = recording
    stem = path.name.split(".")[0]
    rrd = tmp_path / "out" / f"{stem}.rrd"
    proc = replay_saving_rrd(path, tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert f"imported {N_FRAMES} frames of 256x192" in proc.stderr
    rows = [json.loads(line) for line in (tmp_path / "out" / f"{stem}.results.jsonl").read_text().splitlines()]
    assert [r["frame_counter"] for r in rows] == list(range(100, 100 + N_FRAMES))
    _, _, sphere = render(RS_LIKE, RS_SCENE)
    foreground = logged_foreground(rrd)
    assert len(foreground) == N_FRAMES
    for points in foreground:
        assert_on_sphere(points, RS_SCENE, int(sphere.sum()))
    assert pinhole_errors(RS_LIKE, RS_SCENE) > 3e-3  # without the lens model the same check would fail


def test_a_recording_cut_short_imports_its_readable_prefix(recording, tmp_path):
    """The .db3 cut in its messages keeps the frames on its whole pages; the .bag (librealsense writes one LZ4
    chunk per ~MB, then the index) cut in its index keeps every frame: both say where they are damaged."""
    kind, path, _ = recording
    data = path.read_bytes()
    cut = tmp_path / f"cut.{kind}"
    cut.write_bytes(data[:int(len(data) * 0.6)] if kind == "db3" else data[:-40])
    proc = tofd("import", str(cut), str(tmp_path / "cut.mcap"))
    assert proc.returncode == 0, proc.stderr
    written = int(proc.stderr.split("wrote ")[1].split(": ")[1].split(" frames")[0])
    assert 1 <= written <= N_FRAMES - (kind == "db3") and "damaged, the rest unread" in proc.stderr, proc.stderr
    with RealSenseSource(cut) as source:
        frames = list(source)
        rejected = source.take_rejected()
    assert [f.frame_counter for f in frames] == list(range(100, 100 + written))
    assert len(rejected) == 1 and rejected[0].frame_counter == 100 + written
    assert rejected[0].reason.startswith(f"damaged: {cut}")
    if kind == "bag":  # cut inside its only chunk: nothing readable is one line
        cut.write_bytes(data[:len(data) // 2])
        one_line_error(tofd("import", str(cut), str(tmp_path / "none.mcap")), 2, str(cut), "not a readable ROS bag")


def test_an_unreadable_recording_is_one_line_exit_2_naming_it(recording, tmp_path):
    kind, path, _ = recording
    bad = tmp_path / f"bad.{kind}"
    data = bytearray(path.read_bytes())
    bad.write_bytes(bytes(data[:16]) + b"\xff" * 200)  # the magic, then nothing readable
    one_line_error(tofd("import", str(bad), str(tmp_path / "out.mcap")), 2, str(bad))
    assert not (tmp_path / "out.mcap").exists()


def test_replay_of_a_cut_recording_ledgers_the_unreadable_rest(recording, tmp_path):
    kind, path, _ = recording
    data = path.read_bytes()
    cut = tmp_path / f"cut.{kind}"
    cut.write_bytes(data[:int(len(data) * 0.6)] if kind == "db3" else data[:-40])  # as in the import test above
    proc = tofd("replay", str(cut), "--out", str(tmp_path / "out"), "--rerun", "none")
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "out" / "cut.summary.json").read_text()
    drops = json.loads(text[text.index('"drops": ') + len('"drops": '):].split("]", 1)[0] + "]")
    rows = (tmp_path / "out" / "cut.results.jsonl").read_text().splitlines()
    assert 1 <= len(rows) <= N_FRAMES - (kind == "db3")
    assert [(d["frame_counter"], d["stage"]) for d in drops] == [(100 + len(rows), "capture")]
    assert drops[0]["reason"].startswith(f"damaged: {cut}: the rest is unreadable")


def test_a_renamed_recording_is_read_by_its_content(recording, tmp_path):
    kind, path, _ = recording
    renamed = tmp_path / ("capture.bag" if kind == "db3" else "capture.db3")
    renamed.write_bytes(path.read_bytes())
    proc = tofd("import", str(renamed), str(tmp_path / "out.mcap"))
    assert proc.returncode == 0 and f"{N_FRAMES} frames of 256x192" in proc.stderr, proc.stderr
    assert "damaged" not in proc.stderr


@pytest.mark.slow
def test_batch_takes_the_recording_directly(recording, tmp_path):
    kind, path, _ = recording
    proc = tofd("batch", "--out", str(tmp_path / "res"), str(path))
    assert proc.returncode == 0, proc.stderr
    assert f"{N_FRAMES} frames processed, 0 dropped" in proc.stderr, proc.stderr
    assert len(list((tmp_path / "res" / "recording=rs").glob("part-*.parquet"))) == 1
