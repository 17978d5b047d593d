"""Soak: `tofd run --emulate` for N seconds; RSS drift, capture and delivered fps, drops by reason.

    python bench/soak.py --seconds 300

RSS is the sum over tofd and all its children, sampled every second; drift compares the mean of the last
fifth of the run with the mean of the second fifth (after warm-up). Capture fps is frames in per second (the
emulated camera runs at CAMERA_FPS), delivered fps is /metrics' tofd_fps. It passes when tofd exits 0 with a
consistent ledger, the drift is at most MAX_DRIFT_PCT, capture keeps 95 % of CAMERA_FPS without device gaps,
and every drop is a latest-wins one (POLICY_DROPS). Prints a table and writes bench/results/soak.json.
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
sys.path.insert(0, str(ROOT))  # the checkout's tofd_testing package (test support, not installed)

from chaos import tree_rss_mb  # noqa: E402
from report import write_json  # noqa: E402

from tofd_testing.chaos_helpers import free_port, metric, metrics, tofd, wait_for  # noqa: E402
from tofd_testing.pipeline_sources import write_config  # noqa: E402

CAMERA_FPS = 30.0  # the emulated camera's frame rate (INT_TIME register code 30)
MAX_DRIFT_PCT = 5.0
POLICY_DROPS = {"features/superseded", "features/late"}
"""Drops of the live latest-wins policy itself: a newer frame came before this one was sent to a worker, or
was done before it (with two workers, frames finish out of order); anything else is a fault."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0)
    parser.add_argument("--rerun", default="none", help="--rerun of the run (default none)")
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "soak.json", help="JSON written")
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
            in0 = metric(metrics(health), "tofd_frames_in_total")
            while time.monotonic() - t0 < args.seconds and proc.poll() is None:
                time.sleep(1.0)
                rss.append(tree_rss_mb(proc.pid))
                fps.append(metric(metrics(health), "tofd_fps"))
            capture_fps = (metric(metrics(health), "tofd_frames_in_total") - in0) / (time.monotonic() - t0)
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=60)
        finally:
            proc.kill()
        s = json.loads(summary_path.read_text())
    dropped = dict(Counter(f"{d['stage']}/{d['reason'].split(':')[0]}" for d in s["drops"]))
    n = len(rss)
    second, last = rss[n // 5: 2 * n // 5] or rss, rss[4 * n // 5:] or rss
    drift = (sum(last) / len(last)) / (sum(second) / len(second)) - 1
    result = {"title": "Soak (bench/soak.py)",
              "about": "`tofd run --emulate` for `seconds`; RSS of tofd and its children, drift = last fifth vs "
                       "second fifth of the run; capture_fps = frames in per second, fps = delivered (/metrics); "
                       "pass: exit 0, drift <= 5 %, capture >= 95 % of camera_fps without device gaps, only "
                       "latest-wins drops (superseded, late).",
              "cpu_count": os.cpu_count(), "seconds": args.seconds, "rerun": args.rerun, "exit_code": proc.returncode,
              "rss_mb_start": round(sum(second) / len(second), 1), "rss_mb_end": round(sum(last) / len(last), 1),
              "rss_drift_pct": round(100 * drift, 2), "rss_mb_peak": round(max(rss), 1),
              "capture_fps": round(capture_fps, 2), "camera_fps": CAMERA_FPS, "device_gaps": len(s["gaps"]),
              "fps_mean": round(sum(fps) / len(fps), 2), "fps_min": round(min(fps), 2),
              "frames_in": s["frames_in"], "frames_out": s["frames_out"], "frames_dropped": s["frames_dropped"],
              "dropped_by_reason": dropped, "consistent": s["consistent"]}
    checks = {"exit 0, ledger consistent": proc.returncode == 0 and s["consistent"],
              f"RSS drift <= {MAX_DRIFT_PCT:g} %": 100 * drift <= MAX_DRIFT_PCT,
              f"capture >= 95 % of {CAMERA_FPS:g} fps, no device gap": capture_fps >= 0.95 * CAMERA_FPS
              and not s["gaps"],
              "only latest-wins drops": set(dropped) <= POLICY_DROPS}
    result["failed"] = [name for name, ok in checks.items() if not ok]
    result["pass"] = not result["failed"]
    for key, value in result.items():
        print(f"{key:<20} {value}")
    write_json(args.out, result)
    return 0 if result["pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
