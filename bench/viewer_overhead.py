"""Where the Rerun viewer's cost in a lossless replay goes, on the SR3000 clip.

    python bench/viewer_overhead.py                    # 3 rounds of 1200 frames per kind
    python bench/viewer_overhead.py --rounds 5 --frames 2400

Lossless replay of the bundled clip (looped) through the real pipeline, in rounds, each kind once per round:
`none` (no viewer); `handoff` (the daemon's viewer process and its shared-memory hand-off, with a backend that
logs nothing); `process` (the daemon's Rerun viewer process saving an .rrd, batched as a replay is); `inline` (the
same Rerun logging called on the pipeline's sink thread, no process). Per kind: steady fps (after the first tenth),
CPU ms per frame of every process (from /proc, after the first tenth), and per round the fps over the round's
`none`. Then the Rerun logger alone: this process timing RerunBackend on the clip's results (every view, batched
as a replay), CPU per frame including Rerun's own threads. Replay is CPU-bound, so fps over none is about the
pipeline's CPU over the pipeline's plus the viewer's; the budget a ratio of 0.9 leaves the viewer is printed beside
it. Prints a table, writes bench/results/viewer_overhead.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_pipeline import CLIP, Latencies, one_rrd, per_process, processes, with_detector
from report import run_to_end, write_json

from tofd.config import Config, load_config
from tofd.drivers.recording.replay import ReplaySource
from tofd.process_setup import prepare_service_process
from tofd.service.model import load_service_model
from tofd.service.pipeline import Pipeline, maps_read
from tofd.service.pipeline.results import FrameResult
from tofd.service.viewer.logger import frames_per_send
from tofd.service.viewer.process import ViewerProcess
from tofd.service.viewer.rerun_sink import RerunBackend
from tofd.service.viewer.targets import file_footer

KINDS = ("none", "handoff", "process", "inline")
GOAL = 0.9  # replay with Rerun over replay without, issue #48


class NullBackend:
    """A viewer backend that logs nothing: what the viewer process and its hand-off cost by themselves."""

    web_url = None

    def __init__(self, cfg: Config, sink: str, batch_frames: int, footer: bool):
        pass

    def __call__(self, r: FrameResult) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self, timeout_s: float) -> None:
        pass

    def output_problem(self, logged: int, closing: bool) -> str | None:
        return None


def run(cfg: Config, kind: str, frames: int, tmp: Path) -> dict:
    """One lossless replay of `frames` frames of the clip with the viewer of `kind`: steady fps and CPU per frame."""
    rrd = tmp / f"{kind}-{time.monotonic_ns()}.rrd"
    sends = frames_per_send(cfg.rerun, "lossless")
    viewer = inline = None
    if kind == "handoff":
        viewer = ViewerProcess(cfg, "save", sends, open_backend=NullBackend, name="handoff")
    elif kind == "process":
        viewer = ViewerProcess(one_rrd(cfg, rrd), "save", sends, footer=file_footer("lossless"))
    elif kind == "inline":
        inline = RerunBackend(one_rrd(cfg, rrd), "save", sends, footer=True)
    pipeline: Pipeline
    lat = Latencies(frames // 10, lambda: processes(pipeline, viewer))
    pipeline = Pipeline(cfg, "lossless", viewer=viewer, inline_viewer=inline, writers=(lat,),
                        model=load_service_model(cfg), live_source=False, result_maps=maps_read(kind != "none"))
    with ReplaySource(CLIP, loop=True) as source:
        pipeline.start(source, frames)
        run_to_end(pipeline, None)
        usage = per_process(pipeline, viewer, lat, {})
        pipeline.close()
    if viewer is not None:
        viewer.close(60.0)
    if inline is not None:
        inline.close(60.0)
    cpu = {name: p["cpu_ms_per_frame"] for name, p in usage["processes"].items()}
    return {"fps": round(lat.steady_fps() or float("nan"), 1), "cpu_ms_per_frame": cpu,
            "cpu_ms_per_frame_total": round(sum(cpu.values()), 2)}


class Keep:
    """Sink keeping a copy of every result (the pipeline reuses its buffers)."""

    def __init__(self) -> None:
        self.results: list[FrameResult] = []

    def __call__(self, r: FrameResult) -> None:
        f = r.frame
        self.results.append(dataclasses.replace(
            r, frame=dataclasses.replace(f, range_m=f.range_m.copy(), amplitude=f.amplitude.copy()),
            mask=r.mask.copy(), features={k: v.copy() for k, v in r.features.items()}))


def logger_alone(cfg: Config, frames: int, tmp: Path) -> dict:
    """CPU ms per frame (this process, Rerun's threads included) of RerunBackend logging the clip's results, batched
    as a replay, after 20 frames of warm-up; `frames` frames (the clip's results repeated)."""
    keep = Keep()
    pipeline = Pipeline(cfg, "lossless", writers=(keep,), model=load_service_model(cfg), live_source=False,
                        result_maps=maps_read(True))
    with ReplaySource(CLIP) as source:
        pipeline.start(source, None)
        run_to_end(pipeline, None)
        pipeline.close()
    backend = RerunBackend(one_rrd(cfg, tmp / "alone.rrd"), "save", frames_per_send(cfg.rerun, "lossless"),
                           footer=True)
    for r in keep.results[:20]:
        backend(r)
    backend.flush()
    backend.target.rec.flush()
    t0 = time.process_time()
    for i in range(frames):
        backend(keep.results[i % len(keep.results)])
    backend.flush()
    backend.target.rec.flush()
    cpu_ms = (time.process_time() - t0) * 1e3 / frames
    backend.close(60.0)
    return {"frames": frames, "cpu_ms_per_frame": round(cpu_ms, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3, help="rounds, each kind once per round (interleaved)")
    ap.add_argument("--frames", type=int, default=1200, help="frames per replay (the clip looped)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "viewer_overhead.json")
    args = ap.parse_args()
    prepare_service_process()  # as `tofd replay` sets up its process
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        cfg = with_detector(load_config(), tmp_path)
        rounds = [{kind: run(cfg, kind, args.frames, tmp_path) for kind in KINDS} for _ in range(args.rounds)]
        alone = logger_alone(cfg, args.frames, tmp_path)
    rows = []
    for kind in KINDS:
        runs = [r[kind] for r in rounds]
        over = [r[kind]["fps"] / r["none"]["fps"] for r in rounds]
        names = sorted({name for run in runs for name in run["cpu_ms_per_frame"]})
        rows.append({"kind": kind, "fps": float(np.median([run["fps"] for run in runs])),
                     "fps_each": [run["fps"] for run in runs],
                     "over_none": round(float(np.median(over)), 3), "over_none_each": [round(x, 3) for x in over],
                     "cpu_ms_per_frame_total": round(float(np.median([run["cpu_ms_per_frame_total"] for run in runs])),
                                                     2),
                     "cpu_ms_per_frame": {name: round(float(np.median([run["cpu_ms_per_frame"].get(name, 0.0)
                                                                       for run in runs])), 2) for name in names}})
    none_cpu = rows[0]["cpu_ms_per_frame_total"]
    results = {
        "title": "Where the Rerun viewer's cost in a lossless SR3000 replay goes",
        "about": (f"bench/viewer_overhead.py: the bundled clip, {args.frames} frames per lossless replay (looped), "
                  f"{args.rounds} rounds of every kind (medians); none: no viewer; handoff: the viewer process fed "
                  "frame by frame, logging nothing; process: the daemon's Rerun viewer process saving an .rrd; "
                  "inline: the same logging on the sink thread. cpu_ms_per_frame: every process after the first "
                  "tenth; logger_alone: RerunBackend in one process on the clip's results, Rerun's threads "
                  "included."),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_avg_at_start": [round(x, 2) for x in os.getloadavg()]},
        "rows": rows,
        "logger_alone": alone,
        "goal_over_none": GOAL,
        "viewer_budget_ms_per_frame_at_goal": round(none_cpu * (1 / GOAL - 1), 2),
    }
    print(f"{'kind':>8} {'fps':>7} {'over none':>10} {'CPU ms/frame':>13}  per process")
    for r in rows:
        print(f"{r['kind']:>8} {r['fps']:>7} {r['over_none']:>10} {r['cpu_ms_per_frame_total']:>13}  "
              f"{r['cpu_ms_per_frame']}")
    print(f"Rerun logger alone: {alone['cpu_ms_per_frame']} ms CPU per frame; at {GOAL} over none the viewer may "
          f"cost {results['viewer_budget_ms_per_frame_at_goal']} ms per frame")
    write_json(args.out, results)


if __name__ == "__main__":
    main()
