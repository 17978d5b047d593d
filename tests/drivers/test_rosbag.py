"""ROS bags in: bags written with rosbags' writers (ROS 1, ROS 2 sqlite3 and MCAP) from emulated frames import as
tofd recordings that replay like the emulated source, in every encoding; bad bags are one line and exit 2."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.commands.test_cli import CLIP, HANG_GUARD_S, one_line_error, tofd
from tofd.drivers.bags.driver_bag import BagError, RangeOptions, RosbagSource
from tofd.drivers.bags.driver_layouts import LAYOUTS
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config
from tofd_testing.rosbag_helpers import (
    BAG_KINDS,
    TOPICS,
    bag_path,
    camera_info,
    frame_messages,
    image,
    range_image,
    typestore,
    write_bag,
    write_frames_bag,
)
from tofd_testing.rrd_helpers import check_rrd, depth_at

N_FRAMES = 12


@pytest.fixture(scope="module")
def clip_frames() -> list[Frame]:
    """The first frames of the bundled recording of the emulated camera (range in device units, 20 MHz)."""
    return list(itertools.islice(iter_frames(CLIP), N_FRAMES))


def read_bag(path: Path, **options: str) -> tuple[list[Frame], dict[str, int]]:
    with RosbagSource(path, RangeOptions(**options)) as source:  # type: ignore[arg-type]
        return list(source), dict(source.counters)


@pytest.mark.parametrize("kind", BAG_KINDS)
@pytest.mark.parametrize("encoding,unit", [("32FC1", "device"), ("16UC1", "device"), ("16UC1", "mm")])
def test_every_bag_kind_and_encoding_gives_the_frames_back(tmp_path, clip_frames, kind, encoding, unit):
    frames = clip_frames[:3]
    got, counters = read_bag(write_frames_bag(tmp_path, kind, frames, encoding=encoding, unit=unit), range_unit=unit)
    assert len(got) == len(frames) and counters == {}
    for n, (g, f) in enumerate(zip(got, frames, strict=True)):
        assert g.frame_counter == n and g.timestamp_us == f.timestamp_us
        assert g.intrinsics == f.intrinsics
        if unit == "device":  # the SwissRanger's device units at an SR3000 frequency: an SR3000 frame
            assert g.registers is not None and g.registers.mod_freq_hz == 20e6 and g.sensor is None
        else:  # millimetres: no SR3000 registers, the signal as the bag says
            assert g.registers is None and g.sensor is not None and g.sensor.amplitude == "amplitude"
            assert (g.sensor.depth_unit_m, g.sensor.invalid_value) == (1e-3, 0)
        assert np.array_equal(g.amplitude, f.amplitude) and g.amplitude.dtype == np.float32
        assert g.range_m.dtype == np.float32 and np.array_equal(np.isnan(g.range_m), np.isnan(f.range_m))
        if unit == "device":  # 32FC1 and the SwissRanger's own device units: bit for bit
            assert np.array_equal(g.range_m.view(np.uint32), f.range_m.view(np.uint32))
        else:  # millimetres: within the unit
            assert np.nanmax(np.abs(g.range_m - f.range_m)) <= 0.5e-3 + 1e-6


def test_big_endian_padded_rows_and_8_bit_amplitude_decode_like_the_rest(tmp_path, clip_frames):
    frame, ts = clip_frames[0], typestore("ros1")
    stamp = frame.timestamp_us * 1000
    amplitude8 = np.clip(frame.amplitude / 256, 0, 255).astype(np.uint8)
    bag = write_bag(tmp_path / "be.bag", "ros1", [
        (TOPICS["range"], image(ts, range_image(frame, "mono16"), "mono16", stamp, big_endian=True, row_padding=6)),
        (TOPICS["amplitude"], image(ts, amplitude8, "mono8", stamp, row_padding=3)),
        (TOPICS["camera_info"], camera_info(ts, frame, stamp, distortion=-0.2))])
    (got,), _ = read_bag(bag)
    assert np.array_equal(got.range_m.view(np.uint32), frame.range_m.view(np.uint32))
    assert np.array_equal(got.amplitude, amplitude8.astype(np.float32))
    assert got.intrinsics.distortion_model == "plumb_bob" and got.intrinsics.distortion == (-0.2, 0, 0, 0, 0)


def test_a_calibration_that_changes_or_is_missing_is_refused(tmp_path, clip_frames):
    ts = typestore("sqlite3")
    later = dataclasses.replace(clip_frames[1], intrinsics=dataclasses.replace(clip_frames[1].intrinsics, fx=150.0))
    bag = write_bag(bag_path(tmp_path, "sqlite3", "changes"), "sqlite3",
                    frame_messages(ts, clip_frames[0]) + frame_messages(ts, later))
    with pytest.raises(BagError, match=r"calibration changes at stamp \d+\.\d{9} .*fx=150\.0"):
        read_bag(bag)
    uncalibrated = frame_messages(ts, clip_frames[0])  # Intrinsics refuses fx = fy = 0: zero them in the message
    uncalibrated[2][1].k[[0, 4]] = 0.0
    bag = write_bag(bag_path(tmp_path, "sqlite3", "zero"), "sqlite3", uncalibrated)
    with pytest.raises(BagError, match="no usable calibration"):
        read_bag(bag)


def test_z_depth_is_converted_to_radial_range_with_the_camera_info_rays(tmp_path, clip_frames):
    frames = clip_frames[:2]
    bag = write_frames_bag(tmp_path, "ros1", frames, encoding="32FC1", depth="z")
    radial, _ = read_bag(bag, depth="z")
    as_is, _ = read_bag(bag)  # read as radial, the z-depth is short of the range off the axis
    for r, z, f in zip(radial, as_is, frames, strict=True):
        np.testing.assert_allclose(r.range_m, f.range_m, rtol=2e-7, equal_nan=True)
        corner = f.intrinsics.unit_rays()[0, 0, 2]
        assert corner < 0.92 and np.isclose(z.range_m[-1, -1], f.range_m[-1, -1] * corner, rtol=1e-6)


def results(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_an_imported_bag_replays_and_finds_the_nose_like_the_emulated_recording(tmp_path, clip_frames):
    bag = write_frames_bag(tmp_path, "mcap", clip_frames)  # the SwissRanger defaults: mono16 device units
    out = tmp_path / "imported.mcap"
    proc = tofd("import", str(bag), str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {out}: {N_FRAMES} frames of 176x144" in proc.stderr
    for got, want in zip(iter_frames(out), clip_frames, strict=True):
        assert np.array_equal(got.range_m.view(np.uint32), want.range_m.view(np.uint32))
    for source in (out, CLIP, bag):  # the bag also straight into `tofd replay`, imported on the fly
        proc = tofd("replay", str(source), "--out", str(tmp_path / "r"), "--frames", str(N_FRAMES), "--rerun", "none")
        assert proc.returncode == 0, proc.stderr
    imported = results(tmp_path / "r" / "imported.results.jsonl")
    emulated = results(tmp_path / "r" / f"{CLIP.stem}.results.jsonl")
    direct = results(tmp_path / "r" / f"{bag.name}.results.jsonl")
    assert [r["nose_px"] for r in imported] == [r["nose_px"] for r in emulated] == [r["nose_px"] for r in direct]
    truth = [f.ground_truth.nose_px for f in clip_frames]  # type: ignore[union-attr]
    assert all(math.dist(r["nose_px"], t) <= 5 for r, t in zip(imported, truth, strict=True))


def test_a_ros2_driver_bag_has_no_sr3000_registers_but_its_signal_settings_and_driver(tmp_path, clip_frames):
    """An orbbec_camera bag (z-depth 16UC1 mm, mono16 infrared): frames with registers None and a SensorInfo from
    the bag (unit, invalid value, infrared, its full scale, the period of the header stamps, the driver and
    topics); imported to a tofd recording and replayed, they come back the same."""
    layout = next(layout for layout in LAYOUTS if layout.driver == "orbbec_camera")
    ts = typestore("sqlite3")
    messages = []
    for f in clip_frames:
        stamp = f.timestamp_us * 1000
        messages += [(layout.topics["range"], image(ts, range_image(f, "16UC1", "mm", "z"), "16UC1", stamp)),
                     (layout.topics["amplitude"], image(ts, f.amplitude.astype(np.uint16), "mono16", stamp)),
                     (layout.topics["camera_info"], camera_info(ts, f, stamp))]
    bag = write_bag(bag_path(tmp_path, "sqlite3", "orbbec"), "sqlite3", messages)
    frames, counters = read_bag(bag)
    assert len(frames) == N_FRAMES and counters == {}
    sensor = frames[0].sensor
    assert sensor is not None and all(f.registers is None and f.sensor == sensor for f in frames)
    period_us = np.median(np.diff([f.timestamp_us for f in clip_frames]))
    assert (sensor.depth_unit_m, sensor.invalid_value, sensor.amplitude, sensor.amplitude_full_scale) == \
        (1e-3, 0, "ir", 65535.0)
    assert sensor.frame_period_s == pytest.approx(period_us / 1e6) and sensor.unambiguous_range_m is None
    assert sensor.settings["driver"] == "orbbec_camera" and sensor.settings["range_unit"] == "mm"
    assert json.loads(sensor.settings["topics"])["range"] == layout.topics["range"]
    assert frames[0].device.model == "orbbec_camera"
    out = tmp_path / "imported.mcap"
    proc = tofd("import", str(bag), str(out))
    assert proc.returncode == 0, proc.stderr
    info = read_recording_info(out)
    assert (info.registers, info.sensor, info.device) == (None, sensor, frames[0].device)
    replayed = list(iter_frames(out))
    assert len(replayed) == N_FRAMES
    for got, want in zip(replayed, frames, strict=True):
        assert got.registers is None and got.sensor == sensor and got.device == want.device
        assert np.array_equal(got.range_m.view(np.uint32), want.range_m.view(np.uint32))


@pytest.mark.slow
def test_a_bag_of_another_frame_size_goes_through_the_whole_pipeline(tmp_path):
    """224x172 at 62 deg (a PMD-like sensor): the CameraInfo's intrinsics decide everything down to the viewer."""
    w, h, fov = 224, 172, 62.0
    f = (w / 2) / math.tan(math.radians(fov / 2))
    intrinsics = Intrinsics(w, h, f, f, (w - 1) / 2, (h - 1) / 2)
    rng, face, ts = np.random.default_rng(1), load_face("lee_perry_smith"), typestore("ros1")
    truth, messages = [], []
    for n, d in enumerate((0.4, 0.5, 0.6)):
        r = render_face(face, Pose(distance_m=d, yaw_deg=10.0), intrinsics, rng)
        frame = Frame(r.range_m, r.amplitude, n, 1_000_000 * (n + 1), 0.0, 0.0, intrinsics=intrinsics)
        truth.append(r.nose_px)
        messages += frame_messages(ts, frame, encoding="32FC1")
    bag = write_bag(tmp_path / "pmd.bag", "ros1", messages)
    proc = tofd("import", str(bag), str(tmp_path / "pmd.mcap"))
    assert proc.returncode == 0 and "3 frames of 224x172" in proc.stderr, proc.stderr
    proc = subprocess.run([sys.executable, "-m", "tofd", "replay", str(tmp_path / "pmd.mcap"), "--out",
                           str(tmp_path / "r"), "--config", str(bundled_config(tmp_path / "tofd.toml",
                                                                              pipeline=PATIENT_VIEWER))],
                          capture_output=True, text=True, timeout=HANG_GUARD_S,
                          env={**os.environ, "RUST_LOG": "error"})  # with the viewer, saving pmd.rrd
    assert proc.returncode == 0, proc.stderr
    rows = results(tmp_path / "r" / "pmd.results.jsonl")
    assert len(rows) == 3 and all(math.dist(r["nose_px"], t) <= 5 for r, t in zip(rows, truth, strict=True))
    tables = check_rrd(tmp_path / "r" / "pmd.rrd", [0, 1, 2])
    assert depth_at(tables, 2)[1].shape == (h, w)


def bad_bag(tmp_path: Path, clip_frames: list[Frame], change: str) -> Path:
    """A ROS 2 MCAP bag of two frames with one thing wrong."""
    ts = typestore("mcap")
    messages = [m for f in clip_frames[:2] for m in frame_messages(ts, f)]
    stamp = clip_frames[0].timestamp_us * 1000
    if change == "size":
        messages[1] = (TOPICS["amplitude"], image(ts, clip_frames[0].amplitude[:, :160].astype(np.uint16), "16UC1",
                                                  stamp))
    elif change == "encoding":
        messages[0] = (TOPICS["range"], image(ts, np.zeros((144, 176), np.uint8), "mono8", stamp))
    elif change == "unpaired":  # every camera_info one nanosecond off its images' stamp
        messages = [(t, camera_info(ts, f, f.timestamp_us * 1000 + 1) if t == TOPICS["camera_info"] else m)
                    for f in clip_frames[:2] for t, m in frame_messages(ts, f)]
    return write_bag(bag_path(tmp_path, "mcap", change), "mcap", messages)


@pytest.mark.parametrize("change,words", [
    ("size", ["sizes differ", "range image 176x144", "amplitude image 160x144"]),
    ("encoding", ["image_raw16", "encoding 'mono8' is not supported", "32FC1, 16UC1, mono16"]),
    ("unpaired", ["no header stamp has a range image, an amplitude image and a camera_info", "2 camera_info"]),
])
def test_a_bad_bag_is_one_line_exit_2_and_nothing_written(tmp_path, clip_frames, change, words):
    out, bag = tmp_path / "out.mcap", bad_bag(tmp_path, clip_frames, change)
    one_line_error(tofd("import", str(bag), str(out)), 2, *words)
    assert sorted(p.name for p in tmp_path.iterdir()) == [change]  # no OUT, no temp file
    assert one_line_error(tofd("replay", str(bag), "--out", str(tmp_path / "r")), 2, *words).startswith("tofd replay")
    assert not (tmp_path / "r").exists()


def test_a_missing_topic_lists_the_topics_the_bag_has(tmp_path, clip_frames):
    bag = write_frames_bag(tmp_path, "sqlite3", clip_frames[:1])
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap"), "--amplitude-topic", "/tof/amplitude"), 2,
                   "no amplitude topic /tof/amplitude; the bag has:",
                   f"{TOPICS['range']} (sensor_msgs/msg/Image)",
                   f"{TOPICS['camera_info']} (sensor_msgs/msg/CameraInfo)")
    one_line_error(tofd("import", str(bag), str(tmp_path / "out.mcap"), "--camera-info-topic", TOPICS["range"]), 2,
                   f"camera_info topic {TOPICS['range']} is sensor_msgs/msg/Image, expected sensor_msgs/msg/CameraInfo")
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize("name,content", [("junk.bag", b"#ROSBAG V2.0\n\xff\x00garbage"), ("junk.db3", b"not sqlite"),
                                          ("absent.bag", None), ("tofd.mcap", "clip")])
def test_an_unreadable_bag_is_one_line_exit_2(tmp_path, name, content):
    path = tmp_path / name
    if content == "clip":
        path.write_bytes(CLIP.read_bytes()[:200_000])  # a tofd recording is no ROS bag
    elif content is not None:
        path.write_bytes(content)
    one_line_error(tofd("import", str(path), str(tmp_path / "out.mcap")), 2, name)
    assert not (tmp_path / "out.mcap").exists()
