"""`tofd batch` throughput with 1 and 2 local Dask workers against `tofd replay --rerun none` with one feature
worker on the same frames, in one run; CPU seconds per frame of each; the per-partition costs in ms.

    python bench/bench_batch.py [--copies 4] [--partition-frames 50] [--repeats 2] [--json bench/results/batch.json]

Input: --copies copies of the bundled clip (101 frames each) as separate recordings. Baseline: `tofd replay` of
each copy with pipeline.workers = 1 (its summary fps: frames / pipeline time). Batch rate: frames / time from the
first task submitted to the last result (the cluster is started and its workers prepared before).

CPU per frame, all processes of a run: replay: the replay processes' CPU (RUSAGE_CHILDREN) less that of a
`--frames 1` replay per copy (start-up, model and plans), over the frames beyond the first; batch: the Dask
workers' CPU (/proc) plus this process's (client, scheduler, nannies) during run_plan. "cpu bound" is the rate
the workers' own CPU time per frame allows (workers / worker CPU per frame); its ratio to the measured rate shows
how much of the time went to waiting (other jobs on the machine, scheduling, an uneven last round of partitions).
"overhead cores": CPU seconds per second of the run spent outside the tasks (Dask's worker threads, scheduler,
nannies, client): a cost per second, not per frame, so it weighs more the slower a loaded machine runs.
Goal: rate(N workers) >= 0.9 x N x rate(1 worker). Runs are interleaved --repeats times and the fastest of each
kept. "projection": the wall time of 100 hours of 30 fps recordings on 1, 10 and 100 workers from the 1-worker
run's costs (docs/BATCH.md, "Beyond one machine"). Prints tables and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from proc_stats import cpu_s
from report import write_json

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _replay(rec: Path, out: Path, config: Path, *extra: str) -> tuple[dict, float]:
    """The summary of one `tofd replay --rerun none` and the CPU seconds of its processes."""
    before = _children_cpu_s()
    subprocess.run([sys.executable, "-m", "tofd", "replay", str(rec), "--out", str(out), "--rerun", "none",
                    "--config", str(config), *extra], cwd=ROOT, check=True, capture_output=True)
    return json.loads((out / f"{rec.stem}.summary.json").read_text()), _children_cpu_s() - before


def replay_run(recordings: list[Path], tmp: Path) -> dict:
    """Frames/s of `tofd replay --rerun none` with one feature worker over the recordings (frame-weighted) and
    CPU seconds per frame beyond a one-frame replay's."""
    config = tmp / "one_worker.toml"
    text = re.sub(r"(?m)^workers = \d+", "workers = 1", (ROOT / "config" / "tofd.toml").read_text())
    config.write_text(text.replace('model_path = "nose_model.json"',
                                   f'model_path = "{ROOT / "config" / "nose_model.json"}"'))
    frames = seconds = cpu = 0.0
    for rec in recordings:
        summary, rec_cpu = _replay(rec, tmp / f"replay_{rec.stem}", config)
        _, start_cpu = _replay(rec, tmp / f"replay1_{rec.stem}", config, "--frames", "1")
        frames += summary["frames_out"]
        seconds += summary["frames_out"] / summary["fps"]
        cpu += rec_cpu - start_cpu
    return {"frames_per_s": frames / seconds, "cpu_ms_per_frame": 1e3 * cpu / (frames - len(recordings))}


def batch_run(recordings: list[Path], tmp: Path, workers: int, partition_frames: int) -> dict:
    """The summary of `tofd batch` on a fresh local cluster, with the CPU ms per frame of all its processes and
    of its workers alone, the time to prepare the workers and their peak RSS. tofd is imported here, not at the
    top: the workers import this module as they start, and must start as bare as those of `tofd batch`."""
    from tofd.batch.runner import RunOptions, batch_client, prepare, run_plan
    from tofd.batch.task import PrepareWorker
    from tofd.config import load_config

    out = tmp / f"batch_{workers}"
    shutil.rmtree(out, ignore_errors=True)
    # --no-evaluation: the replay it is compared with does not evaluate the model's variants on the ground truth
    inputs, job, digests = prepare([str(r) for r in recordings], str(out), load_config(), partition_frames,
                                   evaluation=False)
    with batch_client(None, workers) as client:
        client.wait_for_workers(workers)
        t0 = time.perf_counter()
        client.register_plugin(PrepareWorker())  # imports and set-up before the CPU readings
        setup_s = time.perf_counter() - t0
        pids = list(client.run(os.getpid).values())
        workers_cpu, own_cpu = sum(map(cpu_s, pids)), time.process_time()
        summary = run_plan(client, inputs, job, str(out), digests, RunOptions(progress=False))
        workers_cpu, own_cpu = sum(map(cpu_s, pids)) - workers_cpu, time.process_time() - own_cpu
        rss = client.run(_peak_rss_mb)
    frames = summary["frames_out"]
    summary["output_bytes_per_frame"] = sum(p.stat().st_size for p in out.rglob("*.parquet")) / frames
    summary["worker_setup_s"] = round(setup_s, 3)
    summary["cpu_ms_per_frame"] = 1e3 * (workers_cpu + own_cpu) / frames
    summary["worker_cpu_ms_per_frame"] = 1e3 * workers_cpu / frames
    tasks_cpu_s = summary["per_partition_ms"]["cpu"] * summary["partitions"]["computed"] / 1e3
    summary["overhead_cores"] = (workers_cpu + own_cpu - tasks_cpu_s) / (frames / summary["throughput_fps"])
    summary["worker_peak_rss_mb"] = round(max(rss.values()), 1)
    return summary


ARCHIVE_HOURS, ARCHIVE_FPS, CLI_PARTITION_FRAMES = 100, 30, 150
"""The projection: an archive of 100 hours of 30 fps recordings, cut into tofd batch's default partitions."""


def projection(one_worker: dict, input_bytes_per_frame: float) -> list[dict]:
    """Wall time of the archive on 1, 10 and 100 workers of one core each, from the 1-worker run's CPU per frame
    (reading, features, rows, the Dask worker's own threads) and fixed costs per partition (setup, writing,
    scheduling), assuming storage keeps up; with the read rate, task rate and output size it needs."""
    frames = ARCHIVE_HOURS * 3600 * ARCHIVE_FPS
    per_part = one_worker["per_partition_ms"]
    fixed_ms = per_part["setup"] + per_part["write"] + per_part["scheduling"]
    ms_per_frame = one_worker["worker_cpu_ms_per_frame"] + fixed_ms / CLI_PARTITION_FRAMES
    rows = []
    for workers in (1, 10, 100):
        wall_s = frames * ms_per_frame / 1e3 / workers
        rows.append({"workers": workers, "wall_h": round(wall_s / 3600, 2),
                     "read_mb_per_s": round(frames * input_bytes_per_frame / wall_s / 1e6, 1),
                     "tasks_per_s": round(frames / CLI_PARTITION_FRAMES / wall_s, 2),
                     "worker_memory_mb": one_worker["worker_peak_rss_mb"]})
    return rows


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--copies", type=int, default=4)
    parser.add_argument("--partition-frames", type=int, default=50)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--json", type=Path, default=Path("bench/results/batch.json"))
    args = parser.parse_args()
    load_start = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        recordings = []
        for k in range(args.copies):
            rec = tmp / f"clip{k}.mcap"
            shutil.copy(CLIP, rec)
            recordings.append(rec)
        replays: list[dict] = []
        runs: dict[int, dict] = {}
        for _ in range(args.repeats):  # interleaved, best of each: other jobs on a shared machine only slow runs down
            replays.append(replay_run(recordings, tmp))
            for w in (1, 2):
                s = batch_run(recordings, tmp, w, args.partition_frames)
                if w not in runs or s["throughput_fps"] > runs[w]["throughput_fps"]:
                    runs[w] = s
        replay = max(replays, key=lambda r: r["frames_per_s"])
    digests = {s["results_digest"] for s in runs.values()}
    input_bytes = CLIP.stat().st_size / runs[1]["frames_out"] * args.copies
    base_fps, base_cpu = replay["frames_per_s"], replay["cpu_ms_per_frame"]
    rows = [{"run": "tofd replay --rerun none (1 worker)", "frames_per_s": round(base_fps, 2), "x_replay": 1.0,
             "cpu_ms_per_frame": round(base_cpu, 2), "cpu_x_replay": 1.0}]
    for w, s in runs.items():
        cpu_bound = w * 1e3 / s["worker_cpu_ms_per_frame"]
        rows.append({"run": f"tofd batch, {w} local worker{'s' * (w > 1)}", "frames_per_s": s["throughput_fps"],
                     "x_replay": round(s["throughput_fps"] / base_fps, 3),
                     "x_1_worker": round(s["throughput_fps"] / runs[1]["throughput_fps"], 3),
                     "goal_x_1_worker": round(0.9 * w, 2),
                     "cpu_ms_per_frame": round(s["cpu_ms_per_frame"], 2),
                     "cpu_x_replay": round(s["cpu_ms_per_frame"] / base_cpu, 3),
                     "worker_cpu_ms_per_frame": round(s["worker_cpu_ms_per_frame"], 2),
                     "cpu_bound_fps": round(cpu_bound, 2), "x_cpu_bound": round(s["throughput_fps"] / cpu_bound, 3),
                     "overhead_cores": round(s["overhead_cores"], 3),
                     "worker_setup_s": s["worker_setup_s"], "worker_peak_rss_mb": s["worker_peak_rss_mb"],
                     **{f"{k}_ms_per_partition": v for k, v in s["per_partition_ms"].items()}})
    print(f"{'run':38}{'frames/s':>9}{'x replay':>9}{'x 1 w':>7}{'goal':>6}{'CPU ms/fr':>10}{'x replay':>9}"
          f"{'x bound':>8}   per partition ms (setup/read/compute/write/scheduling/CPU)")
    for r in rows:
        parts = "/".join(f"{r[k]:.0f}" for k in r if k.endswith("_ms_per_partition"))
        print(f"{r['run']:38}{r['frames_per_s']:9.2f}{r['x_replay']:9.2f}{r.get('x_1_worker', ''):>7}"
              f"{r.get('goal_x_1_worker', ''):>6}{r['cpu_ms_per_frame']:10.2f}{r['cpu_x_replay']:9.2f}"
              f"{r.get('x_cpu_bound', ''):>8}   {parts}")
    result = {
        "about": "tofd batch frames/s with 1 and 2 local Dask workers against tofd replay --rerun none with one "
                 "feature worker, same frames, same run; CPU ms per frame of all processes of each (a ratio that "
                 "holds on a loaded machine); the rate the workers' CPU time allows (cpu bound); per-partition "
                 "costs in ms.",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, load average {load_start:.1f} at the start, "
                   f"{os.getloadavg()[0]:.1f} at the end",
        "repeats": args.repeats, "frames": runs[1]["frames_out"], "partition_frames": args.partition_frames,
        "partitions": runs[1]["partitions"]["total"],
        "identical_results_1_and_2_workers": len(digests) == 1,
        "rows": rows,
        "archive": f"{ARCHIVE_HOURS} h at {ARCHIVE_FPS} fps: {ARCHIVE_HOURS * 3600 * ARCHIVE_FPS} frames, "
                   f"{CLI_PARTITION_FRAMES}-frame partitions, {input_bytes / 1e3:.1f} kB of recording and "
                   f"{runs[1]['output_bytes_per_frame'] / 1e3:.2f} kB of Parquet per frame",
        "projection": projection(runs[1], input_bytes),
    }
    print(f"\nprojection, {result['archive']}:")
    for r in result["projection"]:
        print(f"  {r['workers']:>3} workers: {r['wall_h']:8.2f} h, read {r['read_mb_per_s']} MB/s, "
              f"{r['tasks_per_s']} tasks/s, {r['worker_memory_mb']} MB per worker")
    write_json(args.json, result)


if __name__ == "__main__":
    main()
