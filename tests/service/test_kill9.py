"""`kill -9` of `tofd run --rerun web`: the viewer child and the workers die with it, its shared memory is
gone after the next start, and the next start (same ports) works."""

import json
import os
import signal

import pytest

from tofd_testing.chaos_helpers import alive, children_of, free_port, metric, metrics, shm_segments, tofd, wait_for
from tofd_testing.pipeline_sources import write_config

pytestmark = pytest.mark.slow


def descendants(pid: int) -> set[int]:
    out, todo = set(), [pid]
    while todo:
        kids = children_of(todo.pop())
        out.update(kids)
        todo.extend(kids)
    return out


def start(cfg, health_port, summary=None):
    args = ["run", "--emulate", "--config", cfg, "--rerun", "web", "--health-port", health_port]
    proc = tofd(*args, *(["--summary", summary] if summary else []))
    assert wait_for(lambda: metric(metrics(health_port), "tofd_frames_out_total") >= 10 or proc.poll() is not None,
                    180), "no frames delivered"
    assert proc.poll() is None, proc.communicate()[1]
    return proc


def test_kill9_leaves_no_viewer_no_worker_no_shared_memory(tmp_path):
    cfg = write_config(tmp_path, rerun={"grpc_port": free_port(), "web_port": free_port()})
    health = free_port()
    first = start(cfg, health)
    kids = descendants(first.pid)
    ours = {s for s in shm_segments() if s.startswith(f"tofd_{first.pid}_")}
    assert len(kids) >= 4 and ours  # workers, viewer process, rerun web viewer, resource tracker
    os.kill(first.pid, signal.SIGKILL)
    first.communicate(timeout=30)
    assert wait_for(lambda: not any(alive(k) for k in kids), 30), [k for k in kids if alive(k)]

    summary = tmp_path / "second.json"
    second = start(cfg, health, summary)  # the same viewer and health ports are free again
    try:
        assert not (ours & shm_segments())
        second.send_signal(signal.SIGTERM)
        _, err = second.communicate(timeout=60)
    finally:
        second.kill()
    assert second.returncode == 0, err
    assert json.loads(summary.read_text())["frames_out"] >= 10
