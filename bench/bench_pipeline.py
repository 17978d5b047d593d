"""Pipeline benchmark: live emulated camera at 30 fps, lossless replay throughput, RSS over the live run.

    python bench/bench_pipeline.py                 # short: 20 s live, 600 replayed frames
    python bench/bench_pipeline.py --minutes 10    # the soak: 10 min live (RSS flat within 5 %?)

Every mode runs the real pipeline (2 worker processes, FFT + NFFT + detection) with the daemon's Rerun viewer
process (writing an .rrd to a temp dir, sending as it would to a connected viewer: frame by frame live,
batched in replay) and, for comparison in the same run, without any Rerun sink. Latency is capture (driver
receive) -> sink done; viewer latency is capture -> handed to Rerun in the viewer process, as it logged it
(read back from the .rrd). RSS is the sum over the service process and its workers, sampled every
second; "RSS growth" compares the mean of the last fifth of the run with the mean of the second fifth
(after warm-up). CPU per frame of each process (utime + stime from /proc, after the first tenth of the
frames) gives the compute bound of lossless replay: workers / mean worker CPU time per frame (and, for
comparison, the CPU bound counting the main process too: cores / CPU per frame of every process), and the
main process's share is split by pipeline thread (capture, dispatch, collect, sink); the bench
reports replay without Rerun against it and replay with Rerun against replay without, both as steady
throughput (frames per second over those same frames after the first tenth), each the median over
--replay-pairs pairs of runs back to back (one run varies by 10 % on a shared machine). Prints tables and
writes bench/results/bench_pipeline.json.

--cameras sr3000,640x576 (bench/cameras.py): instead, lossless replay without Rerun of a short rendered clip of
the emulator's face motion (--camera-frames frames, looped to --replay-frames) in each camera geometry, --replay-pairs
runs each, cameras interleaved; per camera the median run's throughput, per-stage p50 times and worker CPU per frame,
and their ratios to the first camera's (the SR3000's) in the same run; and each stage's CPU time per frame (median
over the clip's frames through the workers' FeatureStage in a child process set up like a worker, one thread per
library, the stages' clocks read as CPU time, so other processes' load does not inflate them as it does the wall
times; one pass after each run, the median of the passes); the main process's CPU per frame by thread; then, per
camera, --camera-live-seconds of the clip replayed in real time (30 fps, looped) as a live camera, latest-wins, with
the daemon's Rerun viewer process sending frame by frame: delivered fps and the capture -> viewer latency. Writes
bench/results/bench_pipeline_cameras.json.

    python bench/bench_pipeline.py --cameras sr3000,640x576 --replay-frames 240 --replay-pairs 3
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import platform
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
from cameras import CAMERAS, MemoryCamera, write_face_clip
from proc_stats import cpu_s, own_thread_cpu_s, rss_mb
from report import run_to_end, write_json

from tofd.config import load_config
from tofd.drivers.emulator.backend import open_emulated_camera
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.replay import ReplaySource
from tofd.process_setup import prepare_service_process
from tofd.service.model import load_service_model
from tofd.service.pipeline import Pipeline, maps_read
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.logger import LATENCY, frames_per_send
from tofd.service.viewer.process import ViewerProcess
from tofd.service.viewer.targets import file_footer

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the checkout's tofd_testing package (test support, not installed)
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


THREAD_READ_FRAMES = 50  # the main process's pipeline threads' CPU is read every this many frames (they end)


def thread_cpu_s() -> dict[str, float]:
    """CPU seconds so far of each pipeline thread of this process (tofd-capture, -dispatch, -collect, -sink)."""
    return {t.name.removeprefix("tofd-"): own_thread_cpu_s(t.native_id) for t in threading.enumerate()
            if t.name.startswith("tofd-") and t.native_id is not None}


class Latencies:
    """Sink keeping every delivered frame's end-to-end latency (ms); at the `warmup`-th frame it reads the CPU
    time of every process and the clock, so CPU per frame and steady throughput leave out start-up (imports,
    plans, the first frames' queue fill)."""

    def __init__(self, warmup: int, pids: Callable[[], dict[str, int]]):
        self.ms: list[float] = []
        self.warmup, self._pids = warmup, pids
        self.cpu_at_warmup: dict[str, float] = {}
        self.at_warmup_s = self.last_s = 0.0
        self.threads_at_warmup: dict[str, float] = {}
        self.threads_last: tuple[int, dict[str, float]] = (0, {})

    def __call__(self, r) -> None:
        self.last_s = time.monotonic()
        self.ms.append((self.last_s - r.arrival_s) * 1e3)
        if len(self.ms) == self.warmup:
            self.cpu_at_warmup = {name: cpu_s(pid) for name, pid in self._pids().items()}
            self.at_warmup_s = self.last_s
            self.threads_at_warmup = thread_cpu_s()
        elif (len(self.ms) - self.warmup) % THREAD_READ_FRAMES == 0:
            self.threads_last = (len(self.ms), thread_cpu_s())

    def main_threads_ms_per_frame(self) -> dict[str, float]:
        """CPU ms per frame of each pipeline thread of the main process, from warm-up to its last reading."""
        frames, last = self.threads_last[0] - self.warmup, self.threads_last[1]
        if frames <= 0:
            return {}
        return {name: round((cpu - self.threads_at_warmup.get(name, 0.0)) * 1e3 / frames, 3)
                for name, cpu in sorted(last.items())}

    def steady_fps(self) -> float | None:
        """Frames delivered per second after warm-up: the window CPU per frame is measured over."""
        frames, seconds = len(self.ms) - self.warmup, self.last_s - self.at_warmup_s
        return frames / seconds if frames > 0 and seconds > 0 else None


def processes(pipeline: Pipeline, viewer: ViewerProcess | None) -> dict[str, int]:
    """name -> pid of the service process, its workers and its viewer process."""
    return {"main": os.getpid(), **{f"worker{w.index}": w.pid for w in pipeline.workers if w.pid},
            **({"viewer": viewer.process.pid} if viewer is not None and viewer.process.pid else {})}


def viewer_latencies_ms(rrd: Path) -> np.ndarray:
    """Each frame's capture -> viewer latency (ms), as the viewer process logged it (the "latency" series of
    /timings), read back from the .rrd with Rerun's own reader, in frame order; in a child process, so the reader's
    memory does not count as this process's RSS in the runs after it."""
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as child:
        return np.array(child.submit(read_latencies_ms, str(rrd)).result())


def read_latencies_ms(rrd: str) -> list[float]:
    """viewer_latencies_ms in this process."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        if chunk.entity_path == bp.TIMINGS and not chunk.is_static:
            batch = chunk.to_record_batch()
            rows += zip(batch.column("frame").to_pylist(),
                        (v[LATENCY] for v in batch.column("Scalars:scalars").to_pylist()), strict=True)
    return [ms for _, ms in sorted(rows)]


def per_process(pipeline: Pipeline, viewer: ViewerProcess | None, lat: Latencies,
                rss: dict[str, list[float]]) -> dict:
    """CPU ms per delivered frame after warm-up and RSS (max, MiB) of each process; the workers' mean CPU per
    frame and the compute bound it sets, workers / (mean worker CPU per frame); and the CPU bound of the machine,
    cores / (CPU per frame of every process), which counts the main process's share too."""
    frames = len(lat.ms) - lat.warmup
    out: dict = {}
    for name, pid in processes(pipeline, viewer).items():
        if name in lat.cpu_at_warmup and frames > 0:
            cpu_ms = (cpu_s(pid) - lat.cpu_at_warmup[name]) * 1e3 / frames
            out[name] = {"cpu_ms_per_frame": round(cpu_ms, 2), "rss_mb_max": round(max(rss.get(name) or [0.0]), 1)}
    workers = [v["cpu_ms_per_frame"] for k, v in out.items() if k.startswith("worker")]
    total = sum(workers)  # every frame is computed by exactly one worker
    every = sum(v["cpu_ms_per_frame"] for v in out.values())
    return {"processes": out, "worker_cpu_ms_per_frame": round(total, 2),
            "compute_bound_fps": round(len(workers) * 1e3 / total, 1) if total > 0 else None,
            "cpu_bound_fps": round((os.cpu_count() or 1) * 1e3 / every, 1) if every > 0 else None}


def one_rrd(cfg, path: Path):
    """The config with Rerun saving one .rrd at `path`, never cut into segments (a bench reads it back whole)."""
    return replace(cfg, rerun=replace(cfg.rerun, sink="save", path=str(path), rotate_mb=0.0, rotate_s=0.0))


def with_detector(cfg, tmp: Path):
    """The config, with a nose model learned on rendered frames for the current feature settings
    (tofd_testing/pipeline_sources.py) if the shipped model does not load, so detection is always in the loop."""
    from tofd.config import ConfigError

    try:
        if load_service_model(cfg) is not None:
            return cfg
        reason = "no shipped model"
    except ConfigError as exc:
        reason = str(exc)
    from tofd_testing.pipeline_sources import write_test_model

    print(f"note: {reason}; using a model learned for the current settings")
    model = write_test_model(tmp / "nose_model.json", cfg)
    return replace(cfg, detector=replace(cfg.detector, model_path=str(model)))


def run(cfg, source, policy, *, live: bool, rerun: bool, duration_s: float | None, max_frames: int | None,
        tmp: Path, intrinsics: Intrinsics | None = None) -> dict:
    viewer: ViewerProcess | None = None
    rrd = tmp / f"{policy}-{time.monotonic_ns()}.rrd"
    if rerun:  # the daemon's viewer process, sending as it would to a connected viewer (live: frame by frame)
        sends = frames_per_send(replace(cfg.rerun, sink="connect"), policy)
        viewer = ViewerProcess(one_rrd(cfg, rrd), "save", sends,
                               footer=file_footer(policy))
    pipeline: Pipeline
    warmup = max(1, (max_frames or 300) // 10)
    lat = Latencies(warmup, lambda: processes(pipeline, viewer))
    pipeline = Pipeline(cfg, policy, intrinsics, viewer=viewer, writers=(lat,), model=load_service_model(cfg),
                        live_source=live, result_maps=maps_read(rerun))  # as the daemon's
    rss, rss_parent, stop_sampling = [], [], threading.Event()
    rss_each: dict[str, list[float]] = {}

    def sample() -> None:
        while not stop_sampling.wait(1.0):
            each = {name: rss_mb(pid) for name, pid in processes(pipeline, viewer).items()}
            for name, mb in each.items():
                rss_each.setdefault(name, []).append(mb)
            rss.append(sum(each.values()))
            rss_parent.append(each["main"])

    sampler = threading.Thread(target=sample, daemon=True)
    pipeline.start(source, max_frames)
    sampler.start()
    elapsed = run_to_end(pipeline, duration_s)
    stop_sampling.set()
    usage = per_process(pipeline, viewer, lat, rss_each)
    summary = pipeline.close()
    shown = {}
    if viewer is not None:
        report = viewer.close(60.0)
        seen = viewer_latencies_ms(rrd)[len(lat.ms) // 10:]  # skip the warm-up tenth
        shown = {"viewer_frames": report.get("frames"), "viewer_exit": report["exit"],
                 "viewer_latency_p50_ms": round(float(np.percentile(seen, 50)), 1),
                 "viewer_latency_p99_ms": round(float(np.percentile(seen, 99)), 1)}
    q = pipeline.stats.quantiles_ms()
    latency = np.asarray(lat.ms[len(lat.ms) // 10:])  # skip the warm-up tenth
    n = len(rss)
    return {
        "frames_in": summary["frames_in"], "frames_out": summary["frames_out"],
        "frames_dropped": summary["frames_dropped"], "dropped_by_stage": summary["dropped_by_stage"],
        "consistent": summary["consistent"], "seconds": round(elapsed, 2),
        "fps": round(summary["frames_out"] / elapsed, 2),
        "steady_fps": round(lat.steady_fps() or float("nan"), 2),
        "latency_p50_ms": round(float(np.percentile(latency, 50)), 1),
        "latency_p99_ms": round(float(np.percentile(latency, 99)), 1),
        **shown,
        "stage_p50_ms": {k: round(v[0], 2) for k, v in q.items()},
        "stage_p99_ms": {k: round(v[1], 2) for k, v in q.items()},
        "rss_mb_first": round(rss[0], 1) if rss else None, "rss_mb_max": round(max(rss), 1) if rss else None,
        "rss_growth_pct": round(100 * (np.mean(rss[-max(1, n // 5):]) / np.mean(rss[n // 5: 2 * n // 5]) - 1), 2)
        if n >= 10 else None,
        "rss_mb_every_10s": [round(x) for x in rss[::10]],
        "rss_parent_mb_every_10s": [round(x) for x in rss_parent[::10]],
        **usage,
        "main_thread_cpu_ms_per_frame": lat.main_threads_ms_per_frame(),
    }


MODES = ("live_30fps_rerun", "replay_lossless_rerun", "replay_lossless_no_rerun")


def summarise(results: dict, pairs: list[tuple[dict, dict]]) -> None:
    """Add the goal ratios (median over the replay pairs, each pair run back to back, and every pair's value) and
    two tables (one row per mode, one per mode and process) to the results; the replay modes' rows are the runs
    of the median pair."""
    # steady throughput: over the frames after warm-up, the window the compute bound's CPU times come from
    with_without = [on["steady_fps"] / off["steady_fps"] for on, off in pairs]
    over_bound = [off["steady_fps"] / off["compute_bound_fps"] for _, off in pairs if off["compute_bound_fps"]]
    median = sorted(range(len(pairs)), key=lambda i: with_without[i])[len(pairs) // 2]
    results["replay_lossless_rerun"], results["replay_lossless_no_rerun"] = pairs[median]
    results["replay_pairs"] = len(pairs)
    results["replay_with_over_without_rerun"] = round(float(np.median(with_without)), 3)  # goal >= 0.9
    results["replay_with_over_without_rerun_each"] = [round(x, 3) for x in with_without]
    results["replay_over_compute_bound"] = round(float(np.median(over_bound)), 3) if over_bound else None  # goal >= 0.9
    results["replay_over_compute_bound_each"] = [round(x, 3) for x in over_bound]
    over_cpu = [off["steady_fps"] / off["cpu_bound_fps"] for _, off in pairs if off["cpu_bound_fps"]]
    results["replay_over_cpu_bound"] = round(float(np.median(over_cpu)), 3) if over_cpu else None
    results["mode_rows"] = [{"mode": m, **{k: results[m].get(k) for k in (
        "fps", "steady_fps", "latency_p50_ms", "latency_p99_ms", "viewer_latency_p50_ms", "viewer_latency_p99_ms",
        "frames_in", "frames_out", "frames_dropped", "rss_mb_max", "rss_growth_pct", "worker_cpu_ms_per_frame",
        "compute_bound_fps", "cpu_bound_fps")}} for m in MODES]
    results["process_rows"] = [{"mode": m, "process": name, **usage}
                               for m in MODES for name, usage in results[m]["processes"].items()]


def print_tables(results: dict) -> None:
    print(f"{'mode':28} {'fps':>7} {'steady':>7} {'p50 ms':>7} {'p99 ms':>7} {'viewer p50':>10} {'viewer p99':>10} "
          f"{'in':>6} {'out':>6} {'drop':>5} {'RSS MB':>7} {'RSS +%':>7} {'bound fps':>9}")
    for r in results["mode_rows"]:
        print(f"{r['mode']:28} {r['fps']:7.1f} {r['steady_fps']:7.1f} {r['latency_p50_ms']:7.1f} "
              f"{r['latency_p99_ms']:7.1f} {r['viewer_latency_p50_ms'] or float('nan'):10.1f} "
              f"{r['viewer_latency_p99_ms'] or float('nan'):10.1f} "
              f"{r['frames_in']:6d} {r['frames_out']:6d} {r['frames_dropped']:5d} {r['rss_mb_max'] or 0:7.0f} "
              f"{r['rss_growth_pct'] if r['rss_growth_pct'] is not None else float('nan'):7.2f} "
              f"{r['compute_bound_fps'] or float('nan'):9.1f}")
    live = results["live_30fps_rerun"]
    print("stage p50/p99 ms (live):", {k: (v, live["stage_p99_ms"][k]) for k, v in live["stage_p50_ms"].items()})
    print(f"{'mode':28} {'process':>8} {'CPU ms/frame':>12} {'RSS MB':>7}")
    for r in results["process_rows"]:
        print(f"{r['mode']:28} {r['process']:>8} {r['cpu_ms_per_frame']:12.2f} {r['rss_mb_max']:7.0f}")
    for m in MODES:
        print(f"{m:28} main process threads, CPU ms/frame: {results[m]['main_thread_cpu_ms_per_frame']}")
    r_off = results["replay_lossless_no_rerun"]
    print(f"replay with / without Rerun: {results['replay_with_over_without_rerun']} (goal >= 0.9; median of "
          f"{results['replay_with_over_without_rerun_each']}); "
          f"replay without Rerun / compute bound ({r_off['compute_bound_fps']} fps = {results['workers']} / "
          f"{r_off['worker_cpu_ms_per_frame']} ms worker CPU per frame): {results['replay_over_compute_bound']} "
          f"(goal >= 0.9); against the CPU bound of every process ({r_off['cpu_bound_fps']} fps): "
          f"{results['replay_over_cpu_bound']}; load average at start {results['machine']['load_avg_at_start']}")


WORKER_STAGES = ("segmentation", "fft", "nfft", "detection")  # timed in the workers: the per-frame stage time


def stage_cpu_ms(cfg, clip: Path, intrinsics: Intrinsics) -> dict[str, float]:
    """Median CPU ms per frame of each worker stage over the clip's frames (stage_cpu_ms_here in a child process set
    up like a pipeline worker: one thread per library, arrays kept on the heap)."""
    from tofd.process_setup import THREAD_ENV

    os.environ.update(THREAD_ENV)  # as WorkerHandle.start: the child's libraries load single-threaded
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as child:
        return child.submit(stage_cpu_ms_here, cfg, str(clip), intrinsics).result()


def stage_cpu_ms_here(cfg, clip: str, intrinsics: Intrinsics) -> dict[str, float]:
    """stage_cpu_ms in this process, through FeatureStage with the stages' clocks (time.perf_counter in extract.py
    and stages.py) read as this thread's CPU time."""
    from types import SimpleNamespace

    from tofd.algorithm import extract
    from tofd.process_setup import prepare_compute_process
    from tofd.service.pipeline import stages
    from tofd.service.pipeline.slots import local_slot

    prepare_compute_process()
    stage = stages.FeatureStage(cfg, intrinsics, load_service_model(cfg))
    slot, times = local_slot(intrinsics.shape), {}
    clocks = extract.time, stages.time
    extract.time = stages.time = SimpleNamespace(perf_counter=time.thread_time)
    try:
        with ReplaySource(clip) as source:
            for i, frame in enumerate(source):
                slot["range_m"][...], slot["amplitude"][...] = frame.range_m, frame.amplitude
                timings = stage.run(slot)["timings_ms"]
                for k, v in timings.items():
                    if i >= 2:  # the first frames load plans and caches
                        times.setdefault(k, []).append(v)
    finally:
        extract.time, stages.time = clocks
    return {k: round(float(np.median(v)), 2) for k, v in times.items()}


LIVE_FIELDS = ("latency_p50_ms", "latency_p99_ms", "viewer_latency_p50_ms", "viewer_latency_p99_ms", "viewer_frames",
               "worker_cpu_ms_per_frame")


def live_rerun(cfg, clip: Path, intrinsics: Intrinsics, seconds: float, tmp: Path) -> dict:
    """The clip at 30 fps as a live camera, latest-wins, with the daemon's Rerun viewer process sending frame by frame:
    delivered fps, drops and latencies (capture -> sink, capture -> viewer). `live_*`: handed over from memory as a
    camera's driver hands over raw frames (cameras.MemoryCamera); `realtime_replay_*`: read from the recording in real
    time (ReplaySource, its decompression in the capture thread)."""
    out = {}
    for prefix, source in (("live", MemoryCamera(clip)), ("realtime_replay", ReplaySource(clip, mode="realtime",
                                                                                          loop=True))):
        with source:
            r = run(replace(cfg, intrinsics=intrinsics), source, "latest", live=False, rerun=True,
                    duration_s=seconds, max_frames=None, tmp=tmp)
        out |= {f"{prefix}_fps": r["fps"], f"{prefix}_frames_in": r["frames_in"],
                f"{prefix}_frames_dropped": r["frames_dropped"],
                f"{prefix}_source_skipped": source.counters.get("replay_dropped", 0),
                **{f"{prefix}_{k}": r[k] for k in LIVE_FIELDS},
                f"{prefix}_main_cpu_ms_per_frame": r["processes"].get("main", {}).get("cpu_ms_per_frame"),
                f"{prefix}_main_thread_cpu_ms_per_frame": r["main_thread_cpu_ms_per_frame"],
                f"{prefix}_viewer_cpu_ms_per_frame": r["processes"].get("viewer", {}).get("cpu_ms_per_frame")}
    return out


def compare_cameras(cfg, cameras: list[str], frames: int, replay_frames: int, runs: int, tmp: Path,
                    live_s: float = 0.0) -> dict:
    """Lossless replay without Rerun of a rendered clip per camera, `runs` runs each (cameras interleaved); per camera
    the run of median steady throughput, and ratios to the first camera's; with live_s > 0, then a live run of live_s
    seconds with Rerun per camera (live_rerun)."""
    clips = {}
    for name in cameras:
        print(f"rendering {frames} frames at {name} ...", file=sys.stderr)
        clips[name] = write_face_clip(tmp / f"{name}.mcap", CAMERAS[name], frames)
    each: dict[str, list[dict]] = {name: [] for name in cameras}
    passes: dict[str, list[dict[str, float]]] = {name: [] for name in cameras}
    for _ in range(runs):
        for name in cameras:
            with ReplaySource(clips[name], loop=True) as source:
                each[name].append(run(cfg, source, "lossless", live=False, rerun=False, duration_s=None,
                                      max_frames=replay_frames, tmp=tmp, intrinsics=CAMERAS[name]))
            passes[name].append(stage_cpu_ms(cfg, clips[name], CAMERAS[name]))
    rows, base = [], None
    for name in cameras:
        fps = [r["steady_fps"] for r in each[name]]
        r = each[name][sorted(range(len(fps)), key=fps.__getitem__)[len(fps) // 2]]
        stages = {k: r["stage_p50_ms"].get(k) for k in WORKER_STAGES if k in r["stage_p50_ms"]}
        cpu = {k: round(float(np.median([p[k] for p in passes[name]])), 2) for k in passes[name][0]}
        row = {"camera": name, "pixels": CAMERAS[name].width * CAMERAS[name].height, "fps": r["fps"],
               "steady_fps": r["steady_fps"], "steady_fps_each": fps, "frames_dropped": r["frames_dropped"],
               "worker_cpu_ms_per_frame": r["worker_cpu_ms_per_frame"], "compute_bound_fps": r["compute_bound_fps"],
               "main_cpu_ms_per_frame": r["processes"].get("main", {}).get("cpu_ms_per_frame"),
               "cpu_bound_fps": r["cpu_bound_fps"], "main_thread_cpu_ms_per_frame": r["main_thread_cpu_ms_per_frame"],
               **{f"{k}_p50_ms": v for k, v in stages.items()}, "stage_sum_p50_ms": round(sum(stages.values()), 2),
               **{f"{k}_cpu_ms": cpu[k] for k in WORKER_STAGES if k in cpu},
               "stage_sum_cpu_ms": round(sum(cpu[k] for k in WORKER_STAGES if k in cpu), 2)}
        base = base or row
        row["pixels_over_first"] = round(row["pixels"] / base["pixels"], 2)
        row["stage_sum_over_first"] = round(row["stage_sum_p50_ms"] / base["stage_sum_p50_ms"], 2)
        row["stage_cpu_over_first"] = round(row["stage_sum_cpu_ms"] / base["stage_sum_cpu_ms"], 2)
        row["worker_cpu_over_first"] = round(row["worker_cpu_ms_per_frame"] / base["worker_cpu_ms_per_frame"], 2)
        row["fps_over_first"] = round(row["steady_fps"] / base["steady_fps"], 3)
        if live_s > 0:
            print(f"live {live_s:g} s with Rerun at {name} ...", file=sys.stderr)
            row.update(live_rerun(cfg, clips[name], CAMERAS[name], live_s, tmp))
        rows.append(row)
    return {"about": f"lossless replay, --rerun none, {cfg.pipeline.workers} workers, {replay_frames} frames of a "
                     f"{frames}-frame rendered clip (0.35-0.70 m) per run, median of {runs} runs per camera; "
                     f"ratios against {cameras[0]} in the same run", "cameras": {c: CAMERAS[c].to_dict()
                                                                                  for c in cameras},
            "live_about": f"the clip at 30 fps (looped) as a live camera for {live_s:g} s, latest-wins, with the Rerun "
                          "viewer process sending frame by frame: live_* handed over from memory like a camera's "
                          "raw frames, realtime_replay_* read from the recording in real time" if live_s > 0 else None,
            "rows": rows, "goal_fps_640x576": 30, "goal_stage_sum_over_sr3000": 4, "goal_live_viewer_p99_ms": 66}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=None, help="live run length (default: 20 s)")
    ap.add_argument("--replay-frames", type=int, default=600, help="frames of lossless replay (looped clip)")
    ap.add_argument("--replay-pairs", type=int, default=3,
                    help="replay runs with and without Rerun, back to back; the ratios are their medians")
    ap.add_argument("--cameras", type=lambda text: text.split(","), default=None,
                    help=f"compare lossless replay across camera geometries (of: {', '.join(CAMERAS)}), the first "
                         "the baseline")
    ap.add_argument("--camera-frames", type=int, default=60, help="frames of each camera's rendered clip (--cameras)")
    ap.add_argument("--camera-live-seconds", type=float, default=20.0,
                    help="--cameras: seconds of the live run with Rerun per camera (0: none)")
    ap.add_argument("--out", type=Path, default=None,
                    help="default bench/results/bench_pipeline.json (bench_pipeline_cameras.json with --cameras)")
    args = ap.parse_args()
    prepare_service_process()  # as `tofd run` / `tofd replay` set up their process
    unknown = [c for c in args.cameras or () if c not in CAMERAS]
    if unknown:
        ap.error(f"--cameras: unknown {', '.join(unknown)} (known: {', '.join(CAMERAS)})")
    if args.camera_frames < 2:
        ap.error("--camera-frames: expected >= 2")
    results_dir = ROOT / "bench" / "results"
    cfg = load_config()
    if args.cameras:
        with tempfile.TemporaryDirectory() as tmp:
            cfg = with_detector(cfg, Path(tmp))
            results = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                   "load_avg_at_start": os.getloadavg()},
                       **compare_cameras(cfg, args.cameras, args.camera_frames, args.replay_frames,
                                         args.replay_pairs, Path(tmp), args.camera_live_seconds)}
        for r in results["rows"]:
            print(r)
        write_json(args.out or results_dir / "bench_pipeline_cameras.json", results)
        return
    live_s = args.minutes * 60 if args.minutes else 20.0
    results = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                           "load_avg_at_start": os.getloadavg()}, "workers": cfg.pipeline.workers}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cfg = with_detector(cfg, tmp)
        pairs = []
        for _ in range(args.replay_pairs):
            pair = []
            for rerun in (True, False):
                with ReplaySource(CLIP, loop=True) as source:
                    pair.append(run(cfg, source, "lossless", live=False, rerun=rerun, duration_s=None,
                                    max_frames=args.replay_frames, tmp=tmp))
            pairs.append((pair[0], pair[1]))
        with open_emulated_camera(prerender=True, intrinsics=cfg.intrinsics) as camera:
            results["live_30fps_rerun"] = run(cfg, camera, "latest", live=True, rerun=True, duration_s=live_s,
                                              max_frames=None, tmp=tmp)
    summarise(results, pairs)
    print_tables(results)
    write_json(args.out or results_dir / "bench_pipeline.json", results)


if __name__ == "__main__":
    main()
