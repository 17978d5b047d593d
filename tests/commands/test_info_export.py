"""`tofd info` and `tofd export` as real subprocesses on the bundled recording, a cut copy of it and a ROS 2 bag
written by rosbags; exports read back with OpenCV, a PLY parser and numpy (no pickle)."""

import itertools
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.rosbag_helpers import write_frames_bag

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"
STEM = "emulated_face_035_070"


def tofd(*args):
    return subprocess.run([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


def test_info_describes_the_recording():
    info = read_recording_info(CLIP)
    frames = list(iter_frames(CLIP))
    run = tofd("info", CLIP, "--json")
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert doc["frames"] == info.frame_count == len(frames)
    assert doc["format"] == "tofd recording (MCAP)" and doc["format_version"] == str(info.format_version)
    assert doc["frame_counters"] == [frames[0].frame_counter, frames[-1].frame_counter]
    span_s = (frames[-1].timestamp_us - frames[0].timestamp_us) / 1e6
    assert doc["duration_s"] == pytest.approx(span_s) and doc["rate_hz"] == pytest.approx((len(frames) - 1) / span_s)
    assert doc["intrinsics"] == info.intrinsics.to_dict()
    assert doc["camera"]["serial"] == info.device.serial and doc["damage"] == {"rejected": {}, "stopped": None}
    text = tofd("info", CLIP).stdout
    lines = dict(line.split(":", 1) for line in text.splitlines())
    assert lines["frames"].strip() == f"{len(frames)} (frame counters 0 to {len(frames) - 1})"
    assert lines["damage"].strip() == "none found"
    # the SR3000's lens is a pinhole; its raw distance unit spans c / (2 f_mod) in 16 bits
    unit = 299_792_458.0 / (2 * info.registers.mod_freq_hz) / 65535
    assert doc["lens"] == {"model": "none", "coefficients": {}} and doc["depth_unit_m"] == pytest.approx(unit)
    assert lines["lens"].strip() == "pinhole (no distortion)"
    assert lines["depth unit"].strip() == f"{unit:.6g} m per raw value"


def test_info_reports_the_damage_of_a_cut_recording_and_rejects_other_files(tmp_path):
    cut = tmp_path / "cut.mcap"
    data = CLIP.read_bytes()
    cut.write_bytes(data[: len(data) // 3])
    run = tofd("info", cut, "--json")
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert 0 < doc["frames"] < read_recording_info(CLIP).frame_count  # the readable prefix
    assert doc["damage"]["stopped"].startswith("truncated: ")
    assert "reading stopped early, truncated" in tofd("info", cut).stdout
    run = tofd("info", ROOT / "README.md")
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "README.md" in run.stderr


def test_info_reads_a_ros2_bag(tmp_path):
    frames = list(itertools.islice(iter_frames(CLIP), 4))
    bag = write_frames_bag(tmp_path, "mcap", frames)
    doc = json.loads(tofd("info", bag, "--json").stdout)
    assert doc["format"] == "ROS 2 bag" and doc["details"] == {"storage": "mcap"}
    assert doc["frames"] == 4 and doc["intrinsics"]["width"] == 176
    assert doc["lens"] == {"model": "none", "coefficients": {}}
    assert doc["depth_unit_m"] == pytest.approx(frames[0].registers.depth_unit_m)  # the driver's raw distances
    run = tofd("info", bag, "--range-topic", "/no/such/topic")  # the bag options, as replay and import take them
    assert run.returncode == 2 and "/no/such/topic" in run.stderr and run.stderr.count("\n") == 1


def test_export_png_gives_16_bit_millimetres_and_amplitude(tmp_path):
    frames = list(itertools.islice(iter_frames(CLIP), 2, 4))
    run = tofd("export", CLIP, "--to", "png", "--frames", "2:4", "--out", tmp_path)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{STEM}_{f.frame_counter:06d}_{kind}.png" for f in frames for kind in ("range", "amplitude"))
    for f in frames:
        mm = cv2.imread(str(tmp_path / f"{STEM}_{f.frame_counter:06d}_range.png"), cv2.IMREAD_UNCHANGED)
        assert mm.dtype == np.uint16 and mm.shape == (144, 176)
        valid = np.isfinite(f.range_m)
        assert np.all(np.abs(mm[valid] / 1000.0 - f.range_m[valid]) <= 0.0005) and np.all(mm[~valid] == 0)
        amplitude = cv2.imread(str(tmp_path / f"{STEM}_{f.frame_counter:06d}_amplitude.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(amplitude, np.clip(np.rint(np.nan_to_num(f.amplitude)), 0, 65535).astype(np.uint16))


def read_ply(path: Path) -> np.ndarray:
    """(N, 4) float32 rows of a binary little-endian PLY with four float properties."""
    data = path.read_bytes()
    head, _, body = data.partition(b"end_header\n")
    lines = head.decode().splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    n = int(next(line.split()[2] for line in lines if line.startswith("element vertex")))
    assert [line.split()[2] for line in lines if line.startswith("property")] == ["x", "y", "z", "amplitude"]
    return np.frombuffer(body, "<f4").reshape(n, 4)


def test_export_ply_backprojects_valid_pixels_in_metres(tmp_path):
    frame = next(itertools.islice(iter_frames(CLIP), 5, None))
    run = tofd("export", CLIP, "--to", "ply", "--frames", "5:6", "--out", tmp_path)
    assert run.returncode == 0, run.stderr
    rows = read_ply(tmp_path / f"{STEM}_{frame.frame_counter:06d}.ply")
    valid = np.isfinite(frame.range_m) & (frame.range_m > 0)
    assert len(rows) == np.count_nonzero(valid)
    # the distance of each point from the camera is the pixel's radial range; its direction projects to the pixel
    assert np.allclose(np.linalg.norm(rows[:, :3], axis=1), frame.range_m[valid], rtol=1e-5)
    v, u = np.nonzero(valid)
    assert np.allclose(frame.intrinsics.project(rows[:, :3].astype(np.float64)), np.stack([u, v], axis=1), atol=1e-3)
    assert np.array_equal(rows[:, 3], frame.amplitude[valid])


def test_export_npz_holds_the_frames_without_pickle(tmp_path):
    frames = list(iter_frames(CLIP))[-3:]
    run = tofd("export", CLIP, "--to", "npz", "--frames", f"{len(list(iter_frames(CLIP))) - 3}:", "--out", tmp_path)
    assert run.returncode == 0, run.stderr
    with np.load(tmp_path / f"{STEM}.npz", allow_pickle=False) as npz:
        assert npz["range_m"].shape == (3, 144, 176) and npz["range_m"].dtype == np.float32
        assert np.array_equal(npz["range_m"], np.stack([f.range_m for f in frames]), equal_nan=True)
        assert np.array_equal(npz["amplitude"], np.stack([f.amplitude for f in frames]))
        assert npz["frame_counter"].tolist() == [f.frame_counter for f in frames]
        assert npz["timestamp_us"].tolist() == [f.timestamp_us for f in frames]
        assert float(npz["fx"]) == frames[0].intrinsics.fx and int(npz["width"]) == 176


def test_export_names_a_bad_frame_range():
    run = tofd("export", CLIP, "--to", "npz", "--frames", "5:2")
    assert run.returncode == 2 and "--frames" in run.stderr and run.stderr.count("\n") == 1
