"""Exit statuses and last lines as documented (`tofd --help`): an interrupted replay, a finished live run."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tofd_testing.pipeline_sources import write_config

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def _results_lines(out: Path) -> int:
    """Lines of the results file being written in `out` (under its temp name until the run finishes)."""
    return max((p.read_text().count("\n") for p in out.glob("*results.jsonl*")), default=0)


@pytest.mark.slow
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_replay_says_so_and_exits_128_plus_the_signal(tmp_path, sig, code):
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "replay", CLIP, "--loop", "--rerun", "none", "--out",
                             tmp_path, "--config", write_config(tmp_path)], cwd=ROOT, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "RUST_LOG": "error"})
    try:
        deadline = time.monotonic() + 120
        while _results_lines(tmp_path) < 5 and time.monotonic() < deadline:
            time.sleep(0.2)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"tofd replay: interrupted by {sig.name} after ")
    summary = json.loads((tmp_path / "emulated_face_035_070.summary.json").read_text())
    assert summary["shutdown"]["reason"] == sig.name and summary["consistent"]
    assert last.endswith(f"after {summary['frames_out']} frames")  # --loop: no total


@pytest.mark.slow
def test_a_live_run_reports_its_drops_in_words(tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofd", "run", "--emulate", "--frames", "30", "--health-port", "0",
                          "--config", write_config(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "RUST_LOG": "error"})
    assert run.returncode == 0, run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("tofd run: frames in ") and "{" not in last and "None" not in last
    assert "resource_tracker" not in run.stderr and "leaked" not in run.stderr
