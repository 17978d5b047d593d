"""Soak: `tofd run --emulate` for N seconds; RSS drift, delivered fps, drops by reason.

    python bench/soak.py --seconds 300

RSS is the sum over tofd and all its children, sampled every second, fps from /metrics; drift compares the
mean of the last fifth of the run with the mean of the second fifth (after warm-up). Prints a table and
writes bench/results/soak.json.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from bench_pipeline import rss_mb  # noqa: E402
from chaos import tree  # noqa: E402
from chaos_helpers import free_port, metric, metrics, tofd, wait_for  # noqa: E402
from pipeline_sources import write_config  # noqa: E402
from report import write_json  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--rerun", default="none", help="--rerun of the run (default none)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        health, summary_path = free_port(), Path(tmp) / "summary.json"
        proc = tofd("run", "--emulate", "--config", write_config(Path(tmp)), "--rerun", args.rerun,
                    "--health-port", health, "--summary", summary_path)
        try:
            if not wait_for(lambda: metric(metrics(health), "tofd_frames_out_total") > 0, 180):
                print("soak: no frames", file=sys.stderr)
                return 1
            rss, fps, t0 = [], [], time.monotonic()
            while time.monotonic() - t0 < args.seconds and proc.poll() is None:
                time.sleep(1.0)
                rss.append(rss_mb(tree(proc.pid)))
                fps.append(metric(metrics(health), "tofd_fps"))
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=60)
        finally:
            proc.kill()
        s = json.loads(summary_path.read_text())
    n = len(rss)
    second, last = rss[n // 5: 2 * n // 5] or rss, rss[4 * n // 5:] or rss
    drift = (sum(last) / len(last)) / (sum(second) / len(second)) - 1
    result = {"title": "Soak (bench/soak.py)",
              "about": "`tofd run --emulate` for `seconds`; RSS of tofd and its children, drift = last fifth vs "
                       "second fifth of the run; fps from /metrics.",
              "cpu_count": os.cpu_count(), "seconds": args.seconds, "rerun": args.rerun, "exit_code": proc.returncode,
              "rss_mb_start": round(sum(second) / len(second), 1), "rss_mb_end": round(sum(last) / len(last), 1),
              "rss_drift_pct": round(100 * drift, 2), "rss_mb_peak": round(max(rss), 1),
              "fps_mean": round(sum(fps) / len(fps), 2), "fps_min": round(min(fps), 2),
              "frames_in": s["frames_in"], "frames_out": s["frames_out"], "frames_dropped": s["frames_dropped"],
              "dropped_by_reason": dict(Counter(f"{d['stage']}/{d['reason'].split(':')[0]}" for d in s["drops"])),
              "consistent": s["consistent"]}
    for key, value in result.items():
        print(f"{key:<20} {value}")
    write_json(ROOT / "bench" / "results" / "soak.json", result)
    return 0 if proc.returncode == 0 and s["consistent"] else 1


if __name__ == "__main__":
    sys.exit(main())
