"""A viewer that accepts the Rerun connection and never reads, workers stopped with SIGSTOP: results go on,
viewer frames are dropped and ledgered, SIGTERM exits 0 with the summary written, naming what it had to kill
(real `tofd run --emulate` subprocesses, real TCP peer, real signals)."""

import json
import os
import signal

import pytest

from tofd_testing.chaos_helpers import BlackHole, free_port, metric, metrics, tofd, wait_for, workers_of
from tofd_testing.pipeline_sources import write_config

pytestmark = pytest.mark.slow


def test_stalled_rerun_receiver_hangs_nothing(tmp_path):
    hole, port = BlackHole(), free_port()
    summary_path = tmp_path / "summary.json"
    cfg = write_config(tmp_path, pipeline={"shutdown_timeout_s": 4.0})
    proc = tofd("run", "--emulate", "--config", cfg, "--rerun", f"connect:rerun+http://127.0.0.1:{hole.port}/proxy",
                "--health-port", port, "--summary", summary_path)
    try:
        # the SDK buffers a few hundred MB before its log calls block: wait until the viewer refuses frames
        assert wait_for(lambda: metric(metrics(port), "tofd_viewer_frames_dropped_total", '{reason="blocked"}') > 30,
                        180), "the viewer never stalled"
        out_at_stall = metric(metrics(port), "tofd_frames_out_total")
        assert wait_for(lambda: metric(metrics(port), "tofd_frames_out_total") > out_at_stall + 30, 60), \
            "results stopped while the viewer was stalled"
        stopped = workers_of(proc.pid)[:1]
        for pid in stopped:  # and a worker that will not answer the stop request either
            os.kill(pid, signal.SIGSTOP)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)  # a hang guard: the old code never returned here
    finally:
        proc.kill()
        hole.close()
    assert proc.returncode == 0, err
    summary = json.loads(summary_path.read_text())
    assert summary["consistent"] and summary["frames_pending"] == 0
    assert summary["frames_in"] == summary["frames_out"] + summary["frames_dropped"]
    assert summary["viewer_dropped_by_reason"].get("blocked", 0) > 30
    assert summary["viewer"]["exit"] == "killed"  # abandoned at the deadline, not waited for
    assert summary["error"] is None
    shutdown = summary["shutdown"]
    assert shutdown["reason"] == "SIGTERM" and shutdown["budget_s"] == 4.0
    assert any(part.startswith("viewer (killed") for part in shutdown["abandoned"]), shutdown
    assert len(stopped) == 1 and any(part.endswith("(killed)") and part.startswith("worker")
                                     for part in shutdown["abandoned"]), shutdown


def test_sigterm_with_every_worker_stopped_kills_them_and_writes_the_summary(tmp_path):
    port, summary_path = free_port(), tmp_path / "summary.json"
    cfg = write_config(tmp_path, pipeline={"shutdown_timeout_s": 3.0})
    proc = tofd("run", "--emulate", "--config", cfg, "--rerun", "none", "--health-port", port,
                "--summary", summary_path)
    try:
        assert wait_for(lambda: metric(metrics(port), "tofd_frames_out_total") >= 10, 180), "no frames delivered"
        workers = workers_of(proc.pid)
        for pid in workers:
            os.kill(pid, signal.SIGSTOP)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)  # a hang guard, not a speed check
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    summary = json.loads(summary_path.read_text())
    assert summary["consistent"] and summary["frames_pending"] == 0
    assert summary["frames_in"] == summary["frames_out"] + summary["frames_dropped"]
    shutdown = summary["shutdown"]
    assert shutdown["reason"] == "SIGTERM" and set(shutdown["phases_s"]) == {"pipeline", "health"}
    assert len(workers) == 2
    assert sorted(p for p in shutdown["abandoned"] if p.startswith("worker")) == [
        "worker 0 (killed)", "worker 1 (killed)"], shutdown
    assert all(not os.path.exists(f"/proc/{pid}") or open(f"/proc/{pid}/stat").read().split()[2] == "Z"
               for pid in workers)
