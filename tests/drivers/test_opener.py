"""Inputs recognised by content (tofd.drivers.opener), whatever their names; `tofd import` and `tofd batch` on an
Azure Kinect recording written by Microsoft's recorder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tofd.drivers.k4a.mkv import K4aRecordingSource
from tofd.drivers.opener import identify
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.k4a_helpers import CALIBRATION_JSON, k4a_libraries
from tofd_testing.recording_helpers import write_recording
from tofd_testing.rosbag_helpers import BAG_KINDS, write_frames_bag

ROOT = Path(__file__).resolve().parents[2]


def tofd(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "RUST_LOG": "error"})


@pytest.fixture(scope="module")
def k4a_recording(tmp_path_factory) -> Path:
    """A 6-capture NFOV 2x2 binned recording by libk4arecord: a ramp in depth, IR brighter where nearer."""
    k4a = k4a_libraries()
    v, u = np.indices((288, 320))
    depth = [(600 + 2 * u + v + 5 * k).astype(np.uint16) for k in range(6)]
    ir = [(60000 // (d // 10)).astype(np.uint16) for d in depth]
    path = tmp_path_factory.mktemp("k4a") / "room.mkv"
    return k4a.write_recording(path, "NFOV_2X2BINNED", depth, ir, [9_000_000 + 33_333 * k for k in range(6)],
                               calibration=CALIBRATION_JSON.read_bytes(), serial="000987654321")


def test_inputs_are_recognised_by_content_not_by_name(tmp_path, k4a_recording):
    recording = tmp_path / "takes.dat"
    write_recording(recording, range(2))
    assert identify(recording).name == "tofd"
    disguised = tmp_path / "kinect.mcap"
    shutil.copy(k4a_recording, disguised)
    assert identify(disguised).name == "k4a"
    from tofd_testing.recording_helpers import make_frame
    for kind in BAG_KINDS:
        (tmp_path / kind).mkdir()
        bag = write_frames_bag(tmp_path / kind, kind, [make_frame(0)])
        assert identify(bag).name == "rosbag", kind
        if kind == "ros1":  # the file itself, renamed
            renamed = tmp_path / "ros1.dat"
            shutil.copy(bag, renamed)
            assert identify(renamed).name == "rosbag"
        else:  # the storage file inside the bag directory, sqlite3 or MCAP with the ros2 profile
            storage = next(p for p in bag.iterdir() if p.name != "metadata.yaml")
            assert identify(storage).name == "rosbag", storage.name
    (tmp_path / "empty.mkv").write_bytes(b"")
    (tmp_path / "folder").mkdir()
    (tmp_path / "notes.bag").write_text("# ROSBAG is what this is not")
    for name, why in (("empty.mkv", "an empty file"), ("folder", "a directory without metadata.yaml"),
                      ("notes.bag", "starts with b'# ROSBAG is"), ("missing.mcap", "cannot read")):
        with pytest.raises(ValueError, match="not a recording tofd reads|cannot read") as err:
            identify(tmp_path / name)
        assert str(err.value).startswith(f"{tmp_path / name}: ") and why in str(err.value)


def test_import_keeps_every_frame_and_the_lens(tmp_path, k4a_recording):
    out = tmp_path / "room.mcap"
    proc = tofd("import", k4a_recording, out)
    assert proc.returncode == 0, proc.stderr
    assert "6 frames of 320x288" in proc.stderr
    source = K4aRecordingSource(k4a_recording)
    original = list(source)
    imported = list(iter_frames(out))
    assert [f.frame_counter for f in imported] == [f.frame_counter for f in original] == list(range(6))
    for a, b in zip(original, imported, strict=True):
        np.testing.assert_array_equal(a.range_m.view(np.uint32), b.range_m.view(np.uint32))
        np.testing.assert_array_equal(a.amplitude, b.amplitude)
        assert (a.timestamp_us, a.device, a.intrinsics) == (b.timestamp_us, b.device, b.intrinsics)
    info = read_recording_info(out)
    assert info.intrinsics == source.intrinsics and info.intrinsics.distortion_model == "rational_polynomial"
    assert info.config == {"import": {"file": str(k4a_recording), "format": "k4a"}}


@pytest.mark.slow
def test_batch_takes_a_kinect_recording_by_its_content(tmp_path, k4a_recording):
    renamed = tmp_path / "inputs" / "room.take"
    renamed.parent.mkdir()
    shutil.copy(k4a_recording, renamed)
    out = tmp_path / "out"
    proc = tofd("batch", "--out", out, "--workers", "1", renamed)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "_summary.json").read_text())
    (entry,) = summary["inputs"]
    assert entry["input"] == str(renamed) and entry["frames_in"] == 6 and entry["status"] == "ok", entry
    assert entry["frames_out"] == 6


def test_replay_seek_on_a_kinect_recording_goes_through_an_import(tmp_path, k4a_recording):
    out = tmp_path / "out"
    proc = tofd("replay", k4a_recording, "--seek", "3", "--out", out, "--rerun", "none")
    assert proc.returncode == 0, proc.stderr
    assert "imported 6 frames of 320x288" in proc.stderr
    records = [json.loads(line) for line in (out / "room.results.jsonl").read_text().splitlines()]
    assert [r["frame_counter"] for r in records] == [3, 4, 5]
