"""The viewer process and its shared-memory hand-off (real child process, real .rrd read back with Rerun's
reader): frames arrive in order with their planes, a full hand-off refuses instead of blocking, and a viewer
that dies takes nothing with it."""

import os
import signal
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tests.service.test_track_reporting import MISS, hit, result
from tofd.config import Config
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.process import (
    LIVE_QUEUE_FRAMES,
    QUEUE_FRAMES,
    VIEWER_NICE,
    ViewerProcess,
    hand_off_frames,
)
from tofd_testing.rrd_helpers import image_at, read_entities


def viewer(tmp_path: Path, queue_frames: int = 8) -> tuple[ViewerProcess, Path]:
    cfg = Config()
    path = tmp_path / "v.rrd"
    return ViewerProcess(replace(cfg, rerun=replace(cfg.rerun, sink="save", path=str(path))), "save",
                         queue_frames=queue_frames), path


def shm_of(pid: int) -> list[str]:
    return [p.name for p in Path("/dev/shm").glob(f"tofd_{pid}_viewer_*")]


def test_frames_go_through_the_slots_in_order_with_their_planes(tmp_path):
    v, path = viewer(tmp_path, queue_frames=2)  # fewer slots than frames: each slot is reused
    expected = min(os.getpriority(os.PRIO_PROCESS, 0) + VIEWER_NICE, 19)  # 19: the lowest priority (pytest under nice)
    assert os.getpriority(os.PRIO_PROCESS, v.process.pid) == expected
    frames = [result(k, hit(0.01 * k) if k % 3 else MISS, None) for k in range(12)]
    for k, r in enumerate(frames):
        r.frame.range_m[...] = 0.4 + 0.01 * k  # each frame's own plane
        assert v.offer(r, block_s=30.0)
    assert shm_of(os.getpid())
    report = v.close(30.0)
    assert report == {"exit": "clean", "frames": 12, "errors": 0, "unsent": 0, "path": str(path),
                      "output": str(path)}  # finished: under its own name (it grew under a temp name)
    assert not shm_of(os.getpid())  # unlinked
    tables = read_entities(str(path))
    assert tables[bp.RANGE][1].column("frame").to_pylist() == list(range(12))
    for k, r in enumerate(frames):
        depth = image_at(tables[bp.RANGE][1], "DepthImage", k)
        ray_z = r.frame.intrinsics.unit_rays().astype(np.float32)[..., 2]
        np.testing.assert_array_equal(depth, r.frame.range_m * ray_z)


def test_a_viewer_that_dies_refuses_frames_and_closes_at_once(tmp_path):
    v, _ = viewer(tmp_path, queue_frames=2)
    assert v.offer(result(0, MISS, None), block_s=5.0)
    os.kill(v.process.pid, signal.SIGKILL)
    v.process.join(10.0)
    refused = [v.offer(result(k, MISS, None), block_s=0.2) for k in range(1, 6)]
    assert not any(refused[2:]) and v.stalled  # the dead child never frees a slot
    t0 = time.monotonic()
    report = v.close(20.0)
    assert time.monotonic() - t0 < 5.0, "close waited for a dead child"
    assert report["exit"] == "killed" and report["unsent"] >= 1
    assert not shm_of(os.getpid())


def test_a_wait_for_a_busy_viewer_ends_when_cancelled(tmp_path):
    """A lossless sink waits long for a slot (finish_timeout_s); a stop signal (cancelled) ends that wait."""
    v, _ = viewer(tmp_path, queue_frames=1)
    os.kill(v.process.pid, signal.SIGSTOP)  # a viewer that takes no frame while stopped
    try:
        assert v.offer(result(0, MISS, None), block_s=5.0)  # the one slot
        stop_at = time.monotonic() + 0.5
        t0 = time.monotonic()
        refused = v.offer(result(1, MISS, None), block_s=600.0, cancelled=lambda: time.monotonic() >= stop_at)
        waited = time.monotonic() - t0
    finally:
        os.kill(v.process.pid, signal.SIGCONT)
    assert not refused and v.stalled
    assert 0.5 <= waited < 300.0, waited  # it waited until cancelled, not for the 600 s asked
    assert v.close(60.0)["exit"] == "clean"


def test_a_watched_live_viewer_gets_the_short_hand_off_and_a_record_the_long_one():
    """A live run's viewer someone watches holds at most LIVE_QUEUE_FRAMES (the latest, not a backlog); a file, the
    run's record, and any lossless run keep QUEUE_FRAMES to absorb the viewer's pauses."""
    assert LIVE_QUEUE_FRAMES < QUEUE_FRAMES
    for sink in ("web", "spawn", "connect", "foxglove"):
        assert hand_off_frames("latest", sink) == LIVE_QUEUE_FRAMES
        assert hand_off_frames("lossless", sink) == QUEUE_FRAMES
    assert hand_off_frames("latest", "save") == hand_off_frames("lossless", "save") == QUEUE_FRAMES
