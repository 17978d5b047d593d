"""A viewer that accepts the Rerun connection and never reads: results go on, viewer frames are dropped and
ledgered, SIGTERM exits 0 with the summary written (real `tofd run --emulate` subprocess, real TCP peer)."""

import json
import signal

import pytest
from chaos_helpers import BlackHole, free_port, metric, metrics, tofd, wait_for
from pipeline_sources import write_config

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
