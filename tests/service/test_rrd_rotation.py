"""The live .rrd's size and time limits ([rerun] rotate_mb, rotate_s, keep_files): numbered segments, each a
complete recording read back with Rerun's reader, the oldest deleted beyond keep_files."""

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from tests.service.test_track_reporting import MISS, result
from tofd.algorithm.tracking import NoseTracker
from tofd.config import Config, ConfigError, config_from_dict, load_config
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.rerun_sink import RerunBackend
from tofd.service.viewer.rotation import FileRotation
from tofd_testing.pipeline_sources import PATIENT_VIEWER, write_config
from tofd_testing.rrd_helpers import read_entities

ROOT = Path(__file__).resolve().parents[2]


def logged_frames(path: Path) -> list[int]:
    """Frame counters of the range images in the segment `path` (none in a segment begun just before the stop)."""
    images = read_entities(str(path)).get(bp.RANGE, (None, None))[1]
    return [] if images is None else images.column("frame").to_pylist()


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_time_limit_starts_numbered_segments_and_keeps_the_newest(tmp_path):
    cfg = Config()
    cfg = replace(cfg, rerun=replace(cfg.rerun, sink="save", path=str(tmp_path / "live.rrd"), rotate_s=0.5,
                                     keep_files=2))
    backend = RerunBackend(cfg, "save", 1, False)
    tracker = NoseTracker()
    for k in range(24):
        backend(result(k, MISS, tracker.update(MISS, k * 0.04)))
        time.sleep(0.1)
    backend.flush()
    backend.close(10)
    names = sorted(p.name for p in tmp_path.iterdir())
    last = backend.rotation.index
    assert last >= 3 and names == [f"live.{last - 1:05d}.rrd", f"live.{last:05d}.rrd"]  # older ones deleted
    before, current = (logged_frames(tmp_path / name) for name in names)
    assert before and current and before == list(range(before[0], current[0])) and current[-1] == 23
    # one recording over every segment, each with its static camera and blueprint
    ids = {RrdReader(str(tmp_path / name)).recordings()[0].recording_id for name in names}
    assert ids == {backend.recording_id}
    for name in names:
        assert any(c.is_static for c in read_entities(str(tmp_path / name))[bp.CAMERA][0])


def test_by_default_a_live_file_is_segmented_within_50_gb_and_a_replay_is_one_file():
    rerun = replace(Config().rerun, sink="save")
    assert FileRotation.wanted(rerun, "save", footer=False) and not FileRotation.wanted(rerun, "save", footer=True)
    assert rerun.rotate_mb * (rerun.keep_files + 1) <= 50_000  # MB, however long the run
    assert load_config().rerun == Config().rerun  # the shipped config file says the same


def test_limits_are_checked():
    with pytest.raises(ConfigError, match="rerun.rotate_mb: -1.0 must be >= 0"):
        config_from_dict({"rerun": {"rotate_mb": -1.0}})


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_a_live_run_rotates_its_rrd_by_size(tmp_path):
    summary_path = tmp_path / "summary.json"
    out = tmp_path / "rrd"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "run", "--emulate", "--health-port", "0",
                             "--config", write_config(tmp_path, rerun={"rotate_mb": 2.0}, pipeline=PATIENT_VIEWER),
                             "--rerun", f"save:{out / 'live.rrd'}", "--summary", summary_path], cwd=ROOT,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "RUST_LOG": "error"})
    try:
        deadline = time.monotonic() + 180
        while len(list(out.glob("live.*.rrd"))) < 3 and time.monotonic() < deadline:
            time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    segments = sorted(out.glob("live.*.rrd"))
    assert [p.name for p in segments[:3]] == ["live.00000.rrd", "live.00001.rrd", "live.00002.rrd"]
    assert all(p.stat().st_size >= 2e6 for p in segments[:-1])  # each closed one reached the limit
    frames = [logged_frames(p) for p in segments]
    assert all(frames[:-1])  # only the segment the stop cut short may hold no frame yet
    flat = [f for part in frames for f in part]
    assert flat == sorted(set(flat))  # every logged frame in exactly one segment, in order
    summary = json.loads(summary_path.read_text())
    assert len(flat) + summary["viewer_dropped"] == summary["frames_out"]
