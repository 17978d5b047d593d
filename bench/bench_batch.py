"""`tofd batch` throughput with 1 and 2 local Dask workers against `tofd replay --rerun none` with one feature
worker on the same frames, in one run; the per-partition overhead (setup, reading, writing, scheduling) in ms.

    python bench/bench_batch.py [--copies 4] [--partition-frames 50] [--repeats 2] [--json bench/results/batch.json]

Input: --copies copies of the bundled clip (101 frames each) as separate recordings. Baseline: `tofd replay`
of each copy with pipeline.workers = 1 (its summary fps: frames / pipeline time). Batch rate: frames / time from
the first task submitted to the last result (the cluster is started before). Goal: rate(N workers) >= 0.9 x N x
baseline. Runs are interleaved --repeats times and the best rate of each kept. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from report import write_json

from tofd.batch.runner import RunOptions, batch_client, prepare, run_plan
from tofd.config import load_config

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def replay_fps(recordings: list[Path], tmp: Path) -> float:
    """Frames/s of `tofd replay --rerun none` with one feature worker over the recordings (frame-weighted)."""
    config = tmp / "one_worker.toml"
    config.write_text(re.sub(r"(?m)^workers = \d+", "workers = 1", (ROOT / "config" / "tofd.toml").read_text()))
    frames = seconds = 0.0
    for rec in recordings:
        out = tmp / f"replay_{rec.stem}"
        subprocess.run([sys.executable, "-m", "tofd", "replay", str(rec), "--out", str(out), "--rerun", "none",
                        "--config", str(config)], cwd=ROOT, check=True, capture_output=True)
        summary = json.loads((out / f"{rec.stem}.summary.json").read_text())
        frames += summary["frames_out"]
        seconds += summary["frames_out"] / summary["fps"]
    return frames / seconds


def batch_run(recordings: list[Path], tmp: Path, workers: int, partition_frames: int) -> dict:
    out = tmp / f"batch_{workers}"
    shutil.rmtree(out, ignore_errors=True)
    inputs, job, digests = prepare([str(r) for r in recordings], str(out), load_config(), partition_frames)
    with batch_client(None, workers) as client:
        summary = run_plan(client, inputs, job, str(out), digests, RunOptions(progress=False))
        rss = client.run(_peak_rss_mb)
    summary["worker_peak_rss_mb"] = round(max(rss.values()), 1)
    return summary


def _peak_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--copies", type=int, default=4)
    parser.add_argument("--partition-frames", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, default=Path("bench/results/batch.json"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        recordings = []
        for k in range(args.copies):
            rec = tmp / f"clip{k}.mcap"
            shutil.copy(CLIP, rec)
            recordings.append(rec)
        baselines: list[float] = []
        runs: dict[int, dict] = {}
        for _ in range(args.repeats):  # interleaved, best of each: other jobs on a shared machine only slow runs down
            baselines.append(replay_fps(recordings, tmp))
            for w in (1, 2):
                s = batch_run(recordings, tmp, w, args.partition_frames)
                if w not in runs or s["throughput_fps"] > runs[w]["throughput_fps"]:
                    runs[w] = s
        baseline = max(baselines)
    digests = {s["results_digest"] for s in runs.values()}
    rows = [{"run": "tofd replay --rerun none (1 worker)", "frames_per_s": round(baseline, 2), "x_replay": 1.0}]
    for w, s in runs.items():
        rows.append({"run": f"tofd batch, {w} local worker{'s' * (w > 1)}", "frames_per_s": s["throughput_fps"],
                     "x_replay": round(s["throughput_fps"] / baseline, 3),
                     "goal_x": round(0.9 * w, 2), "worker_peak_rss_mb": s["worker_peak_rss_mb"],
                     **{f"{k}_ms_per_partition": v for k, v in s["per_partition_ms"].items()}})
    print(f"{'run':40}{'frames/s':>10}{'x replay':>10}{'goal':>6}   per partition ms (setup/read/compute/write/sched)")
    for r in rows:
        parts = "/".join(f"{r[k]:.0f}" for k in r if k.endswith("_ms_per_partition"))
        print(f"{r['run']:40}{r['frames_per_s']:10.2f}{r['x_replay']:10.2f}{r.get('goal_x', ''):>6}   {parts}")
    result = {
        "about": "tofd batch frames/s with 1 and 2 local Dask workers against tofd replay --rerun none with one "
                 "feature worker, same frames, same run; per-partition costs in ms.",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end",
        "repeats": args.repeats, "frames": runs[1]["frames_out"], "partition_frames": args.partition_frames,
        "partitions": runs[1]["partitions"]["total"],
        "identical_results_1_and_2_workers": len(digests) == 1,
        "rows": rows,
    }
    write_json(args.json, result)


if __name__ == "__main__":
    main()
