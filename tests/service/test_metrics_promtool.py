"""/metrics of a real `tofd run` passes Prometheus's own linter, `promtool check metrics` (Debian: prometheus)."""

import os
import re
import shutil
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from tofd_testing.pipeline_sources import write_config

ROOT = Path(__file__).resolve().parents[2]
PROMTOOL = shutil.which("promtool")


@pytest.mark.slow
@pytest.mark.skipif(PROMTOOL is None, reason="promtool is not installed (Debian package prometheus; .ci/run has it)")
def test_every_metric_family_passes_promtool(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "run", "--emulate", "--config", write_config(tmp_path),
                             "--health-port", "0"], cwd=ROOT, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "RUST_LOG": "error"})
    try:
        base = next(m.group(1) for line in proc.stderr if (m := re.search(r"health: (http://\S+)/healthz", line)))
        text = ""
        while "tofd_stage_duration_rolling_seconds{" not in text:  # the first frames delivered
            text = urllib.request.urlopen(base + "/metrics", timeout=10).read().decode()
        lint = subprocess.run([PROMTOOL, "check", "metrics"], input=text, capture_output=True, text=True,
                              timeout=60)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    assert lint.returncode == 0, lint.stdout + lint.stderr
    assert "# TYPE tofd_stage_duration_rolling_seconds summary" in text
    assert re.search(r'^tofd_stage_duration_rolling_seconds\{quantile="0.99",stage="nfft"\} \S+$', text, re.M)
    assert "# TYPE tofd_nose_detected_frames_total counter" in text  # the detector's families are checked too
