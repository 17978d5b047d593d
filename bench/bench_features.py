"""Benchmark: FFT and NFFT feature time per frame on a sphere and a rendered face at 0.35, 0.5, 0.7 m.

Times are wall-clock (median, p95) plus the NFFT's CPU time (thread_time), which stays meaningful when
other processes share the cores. 1 thread: --processes fresh processes one after another, frames one after another,
their frames pooled. 2 threads: two
worker processes computing frames at the same time (finufft/scipy with nthreads=1 each; finufft's
own threading was catastrophic on this 2-core machine, see design/nfft_notes.md), reported as
per-frame time = wall time / frames of both. eps0 error: largest relative deviation of the NFFT eps0 from the
converged solution (CG to a 1e-9 band residual, NUFFTs to 1e-9, in double precision) over the pixels where the
converged eps0 is at least a tenth of its peak (the pixels a detector box can accept). Goal: NFFT / FFT <= 2 on CPU
time at 176x144. The NFFT CPU time is split into its stages: points (back-projection
into the patch) and map writing, type 1 (the finufft type-1 NUFFT onto the 2N grid giving the Toeplitz kernel and
A^H z), CG (the conjugate-gradient solve; also per iteration: one Toeplitz product, a real FFT pair of size 2N, plus
the CG updates) and type 2 (the forward NUFFT of the filtered fields, with the set-up around the solve: the points
handed to finufft, the operator made from the kernel).
"without CG": the NFFT/FFT ratio of the other stages alone, the least any CG speed-up can reach. "floor": what the
path would cost with no overhead at all and a stopping rule that knew the answer, as a ratio to the FFT path: the
time inside finufft's own calls (nufft) plus the fewest CG iterations that put eps0 within 1 % of converged, each at
the measured cost of one iteration.
--cameras: the camera geometries to run (bench/cameras.py: the SR3000 and three current ones), each with its own FFT
baseline measured in the same run, so the ratios compare per geometry; and the cross-camera check: the NFFT eps0 at a
0.1 m sphere's apex for every camera at 0.35, 0.5 and 0.8 m, and its spread (goal <= 2 %).
Prints a table and writes JSON (bench/results/bench_features.json or --out).

    .venv/bin/python bench/bench_features.py [--repeats 50] [--processes 3] [--cameras sr3000,640x576] [--out PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import multiprocessing as mp
import platform
import time
from pathlib import Path

import finufft
import numpy as np
from cameras import CAMERAS
from report import write_json

from tofd.algorithm.features import FFTFeatures, NFFTFeatures
from tofd.algorithm.features import nfft as nfft_module
from tofd.algorithm.segmentation import segment
from tofd.config import FeatureConfig, SegmentationConfig
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic
from tofd.lab import sphere_experiment
from tofd.process_setup import keep_arrays_on_the_heap

DISTANCES_M = (0.35, 0.5, 0.7)
SPHERE_CHECK_M = (0.35, 0.5, 0.8)  # the cross-camera check's apex distances, metres


GOAL_RATIO = 2.0  # NFFT / FFT range-feature CPU time per frame at 176x144
STAGE_COLUMNS = ("points", "type1", "cg", "type2")  # the NFFT CPU time's parts (points: with the map writing)
TIMED_COLUMNS = (*STAGE_COLUMNS, "nufft")  # and finufft's calls alone, inside type1 and type2
ABOUT = ("FFT and NFFT range features per frame, CPU milliseconds (thread time), per camera geometry; ratios within "
         "one run. NFFT stages: points (back-projection into the patch, and the map writing), type1 (finufft type 1 "
         "onto the 2N grid: Toeplitz kernel and A^H z), cg (the solve), type2 (finufft type 2 of the filtered fields, "
         "with the set-up around the solve). nfft_without_cg_over_fft_cpu: the ratio of the other stages alone, the "
         "least a faster solve can reach. eps0_error_pct: largest deviation from the converged solution where it is "
         "at least a tenth of its peak. nufft_cpu_median_ms: finufft's own calls (setpts, execute) inside type1 and "
         "type2. cg_fewest_iterations: the fewest CG iterations whose eps0 is within 1 % of converged. "
         "floor_over_fft_cpu: (nufft + cg_fewest_iterations x cg_cpu_per_iteration_ms) / FFT, the least the path "
         "can cost without a cheaper NUFFT or Toeplitz product.")
CONVERGED = {"cg_tolerance": 1e-9, "cg_max_iterations": 3000, "cg_precision": "double", "nufft_eps": 1e-9}
FACE_DEPTH_M = 0.08  # metres: segmentation depth margin for the face scenes, the whole face (a worst case: 1,700-5,600
# points; the detector's default 0.025 m keeps a third of that)


def scenes(intrinsics: Intrinsics) -> list[tuple[str, float, np.ndarray, np.ndarray]]:
    """(name, distance, range_m, mask): an ideal 0.15 m sphere and a rendered, noisy, segmented face."""
    out = []
    face = load_face("lee_perry_smith")
    seg = SegmentationConfig(depth_margin_m=FACE_DEPTH_M)
    for d in DISTANCES_M:
        s = synthetic.sphere(intrinsics, d, 0.15)
        out.append(("sphere", d, s.range_m.astype(np.float32), s.mask))
        r = render_face(face, Pose(distance_m=d, yaw_deg=15.0, pitch_deg=5.0), intrinsics, np.random.default_rng(1))
        out.append(("face", d, r.range_m, segment(r.range_m, r.amplitude, seg, intrinsics)))
    return out


def eps0_error(eps0: np.ndarray, converged: np.ndarray) -> float:
    """Largest |eps0 / converged - 1| over the pixels where converged >= a tenth of its peak."""
    strong = np.isfinite(converged) & (converged >= 0.1 * np.nanmax(converged))
    return float(np.max(np.abs(eps0[strong] / converged[strong] - 1.0)))


STAGES = {"fields": (NFFTFeatures, "fields"), "type1": (nfft_module, "real_pair_spectra"), "cg": (nfft_module, "solve"),
          "nufft_setpts": (finufft.Plan, "setpts"), "nufft_execute": (finufft.Plan, "execute")}
FLOOR_ERROR = 1e-2  # the eps0 accuracy of the goal: within 1 % of converged


def count_stage_cpu(totals: dict[str, float]) -> None:
    """Make each of the NFFT path's STAGES add its CPU time (s) to totals[stage] (this process only; replaces an
    earlier call's counters). The nufft_ stages are finufft's own calls, wherever the path makes them."""
    for stage, (owner, name) in STAGES.items():
        function = getattr(owner, name)
        function = getattr(function, "__wrapped__", function)

        @functools.wraps(function)
        def timed(*args, _function=function, _stage=stage, **kwargs):
            start = time.thread_time()
            try:
                return _function(*args, **kwargs)
            finally:
                totals[_stage] += time.thread_time() - start

        setattr(owner, name, timed)


def fewest_iterations(intrinsics: Intrinsics, cfg: FeatureConfig, range_m: np.ndarray, mask: np.ndarray,
                      converged: np.ndarray) -> int:
    """The fewest CG iterations whose eps0 is within FLOOR_ERROR of `converged` (what a stopping rule that knew the
    answer would spend; cfg.cg_max_iterations if none is)."""
    for iterations in range(1, cfg.cg_max_iterations):
        capped = dataclasses.replace(cfg, cg_tolerance=1e-12, cg_max_iterations=iterations)
        if eps0_error(NFFTFeatures(intrinsics, capped).range_features(range_m, mask).eps0, converged) <= FLOOR_ERROR:
            return iterations
    return cfg.cg_max_iterations


def time_frames(cfg_dict: dict, repeats: int, camera: str = "sr3000") -> list[dict]:
    """Per scene: FFT and NFFT range-feature times (ms, wall and CPU) over `repeats` frames, the NFFT's CPU time per
    stage, CG iterations and the eps0 error against the converged solution; the heap set up as in the pipeline's
    feature workers."""
    keep_arrays_on_the_heap()
    totals = dict.fromkeys(STAGES, 0.0)
    count_stage_cpu(totals)
    intrinsics = CAMERAS[camera]
    cfg = FeatureConfig(**cfg_dict)
    fft, nfft = FFTFeatures(intrinsics, cfg), NFFTFeatures(intrinsics, cfg)
    converged = NFFTFeatures(intrinsics, dataclasses.replace(cfg, **CONVERGED))
    rows = []
    for name, d, range_m, mask in scenes(intrinsics):
        fft.range_features(range_m, mask)
        reference = converged.range_features(range_m, mask).eps0
        error = eps0_error(nfft.range_features(range_m, mask).eps0, reference)
        fewest = fewest_iterations(intrinsics, cfg, range_m, mask, reference)
        t_fft, t_nfft, cpu_fft, cpu_nfft, its = [], [], [], [], []
        stages: dict[str, list[float]] = {f"{s}_cpu_ms": [] for s in TIMED_COLUMNS}
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.thread_time()
            fft.range_features(range_m, mask)
            t1, c1, before = time.perf_counter(), time.thread_time(), dict(totals)
            maps = nfft.range_features(range_m, mask)
            t2, c2 = time.perf_counter(), time.thread_time()
            spent = {k: (totals[k] - before[k]) * 1e3 for k in totals}
            for stage, ms in (("points", (c2 - c1) * 1e3 - spent["fields"]), ("type1", spent["type1"]),
                              ("cg", spent["cg"]), ("type2", spent["fields"] - spent["type1"] - spent["cg"]),
                              ("nufft", spent["nufft_setpts"] + spent["nufft_execute"])):
                stages[f"{stage}_cpu_ms"].append(ms)
            t_fft.append((t1 - t0) * 1e3)
            t_nfft.append((t2 - t1) * 1e3)
            cpu_fft.append((c1 - c0) * 1e3)
            cpu_nfft.append((c2 - c1) * 1e3)
            its.append(maps.iterations)
        rows.append({"camera": camera, "scene": name, "distance_m": d, "points": int(mask.sum()), "fft_ms": t_fft,
                     "nfft_ms": t_nfft, "fft_cpu_ms": cpu_fft, "nfft_cpu_ms": cpu_nfft, **stages,
                     "iterations": int(np.median(its)), "fewest_iterations": fewest,
                     "eps0_error": error})
    return rows


def pooled(runs: list[list[dict]]) -> list[dict]:
    """Per scene, the frames of several time_frames runs together (their per-frame lists concatenated)."""
    timed = ("fft_ms", "nfft_ms", "fft_cpu_ms", "nfft_cpu_ms", *(f"{s}_cpu_ms" for s in TIMED_COLUMNS))
    return [dict(rows[0], **{k: [x for r in rows for x in r[k]] for k in timed}) for rows in zip(*runs, strict=True)]


def stats(rows: list[dict], threads: int, wall_s: float | None = None) -> list[dict]:
    out = []
    for r in rows:
        fft, nfft = np.array(r["fft_ms"]), np.array(r["nfft_ms"])
        per_iteration = float(np.median(r["cg_cpu_ms"]) / max(r["iterations"], 1))
        floor = float(np.median(r["nufft_cpu_ms"])) + r["fewest_iterations"] * per_iteration
        out.append({"camera": r["camera"], "threads": threads, "scene": r["scene"], "distance_m": r["distance_m"],
                    "points": r["points"],
                    "fft_median_ms": float(np.median(fft)), "fft_p95_ms": float(np.percentile(fft, 95)),
                    "nfft_median_ms": float(np.median(nfft)), "nfft_p95_ms": float(np.percentile(nfft, 95)),
                    "fft_cpu_median_ms": float(np.median(r["fft_cpu_ms"])),
                    "nfft_cpu_median_ms": float(np.median(r["nfft_cpu_ms"])),
                    **{f"{s}_cpu_median_ms": float(np.median(r[f"{s}_cpu_ms"])) for s in TIMED_COLUMNS},
                    "cg_cpu_per_iteration_ms": per_iteration,
                    "cg_iterations": r["iterations"], "cg_fewest_iterations": r["fewest_iterations"],
                    "eps0_error_pct": 100 * r["eps0_error"],
                    "nfft_over_fft": float(np.median(nfft) / np.median(fft)),
                    "nfft_over_fft_cpu": float(np.median(r["nfft_cpu_ms"]) / np.median(r["fft_cpu_ms"])),
                    "nfft_without_cg_over_fft_cpu": float(np.median(np.subtract(r["nfft_cpu_ms"], r["cg_cpu_ms"]))
                                                          / np.median(r["fft_cpu_ms"])),
                    "floor_over_fft_cpu": floor / float(np.median(r["fft_cpu_ms"]))})
    return out


def sphere_apex_eps0(cfg: FeatureConfig) -> dict[str, list[float]]:
    """Per camera, the NFFT eps0 (m^2) at the apex of a 0.1 m sphere at each of SPHERE_CHECK_M."""
    out = {}
    for name, intrinsics in CAMERAS.items():
        nfft, apex = NFFTFeatures(intrinsics, cfg), (int(round(intrinsics.cy)), int(round(intrinsics.cx)))
        out[name] = [float(nfft.range_features(s.range_m, s.mask).eps0[apex])
                     for s in (synthetic.sphere(intrinsics, d, 0.1) for d in SPHERE_CHECK_M)]
    return out


def measure(cfg: dict, camera: str, repeats: int, processes: int) -> tuple[list[dict], list[float], float]:
    """One camera: rows of 1-thread (pooled over `processes` fresh processes) and 2-process stats, each process's
    worst NFFT/FFT CPU ratio, and the 2-process wall time per frame (ms)."""
    ctx = mp.get_context("spawn")
    runs = []
    for _ in range(processes):  # one after another, each in a fresh process
        with ctx.Pool(1) as pool:
            runs.append(pool.apply(time_frames, (cfg, repeats, camera)))
    process_worst = [max(r["nfft_over_fft_cpu"] for r in stats(run, 1)) for run in runs]
    with ctx.Pool(2) as pool:
        pool.starmap(time_frames, [(cfg, 2, camera)] * 2)  # warm up imports and plans
        t0 = time.perf_counter()
        both = pool.starmap(time_frames, [(cfg, repeats, camera)] * 2)
        wall = time.perf_counter() - t0
    frames = 2 * repeats * len(both[0])
    return stats(pooled(runs), 1) + stats(pooled(both), 2), process_worst, wall * 1e3 / frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50, help="frames per scene and path")
    parser.add_argument("--processes", type=int, default=3,
                        help="fresh processes the 1-thread times are measured in, one after another (the FFT path's "
                             "time varies between processes)")
    parser.add_argument("--cameras", default="sr3000", type=lambda text: text.split(","),
                        help=f"comma-separated camera geometries to time (of: {', '.join(CAMERAS)}); default sr3000")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_features.json"))
    args = parser.parse_args()
    unknown = [c for c in args.cameras if c not in CAMERAS]
    if unknown:
        parser.error(f"--cameras: unknown {', '.join(unknown)} (known: {', '.join(CAMERAS)})")
    cfg = dataclasses.asdict(FeatureConfig())

    rows, per_camera = [], {}
    for camera in args.cameras:
        camera_rows, process_worst, throughput_ms = measure(cfg, camera, args.repeats, args.processes)
        rows += camera_rows
        single = [r for r in camera_rows if r["threads"] == 1]
        per_camera[camera] = {"worst_nfft_over_fft_cpu": max(r["nfft_over_fft_cpu"] for r in single),
                              "worst_nfft_over_fft_cpu_per_process": process_worst,
                              "worst_eps0_error_pct": max(r["eps0_error_pct"] for r in single),
                              "worst_nfft_without_cg_over_fft_cpu": max(r["nfft_without_cg_over_fft_cpu"]
                                                                        for r in single),
                              "floor_over_fft_cpu": [min(r["floor_over_fft_cpu"] for r in single),
                                                     max(r["floor_over_fft_cpu"] for r in single)],
                              "two_process_wall_ms_per_frame": throughput_ms}

    header = (f"{'camera':>9} {'thr':>3} {'scene':>6} {'dist':>5} {'points':>6} {'FFT med':>8} {'FFT p95':>8} "
              f"{'FFT cpu':>8} {'NFFT med':>9} {'NFFT p95':>9} {'NFFT cpu':>9} {'pts+map':>7} {'type1':>6} "
              f"{'CG cpu':>7} {'type2':>6} {'nufft':>6} {'CG it':>6} {'fewest':>6} {'ms/it':>6} "
              f"{'eps0 err%':>9} {'NFFT/FFT':>9} {'cpu ratio':>9} {'floor':>6}")
    print(header)
    for r in rows:
        print(f"{r['camera']:>9} {r['threads']:>3} {r['scene']:>6} {r['distance_m']:5.2f} {r['points']:6d} "
              f"{r['fft_median_ms']:8.2f} {r['fft_p95_ms']:8.2f} {r['fft_cpu_median_ms']:8.2f} "
              f"{r['nfft_median_ms']:9.2f} {r['nfft_p95_ms']:9.2f} {r['nfft_cpu_median_ms']:9.2f} "
              f"{r['points_cpu_median_ms']:7.2f} {r['type1_cpu_median_ms']:6.2f} {r['cg_cpu_median_ms']:7.2f} "
              f"{r['type2_cpu_median_ms']:6.2f} {r['nufft_cpu_median_ms']:6.2f} {r['cg_iterations']:6d} "
              f"{r['cg_fewest_iterations']:6d} {r['cg_cpu_per_iteration_ms']:6.3f} "
              f"{r['eps0_error_pct']:9.2f} {r['nfft_over_fft']:9.1f} {r['nfft_over_fft_cpu']:9.1f} "
              f"{r['floor_over_fft_cpu']:6.1f}")
    for camera, c in per_camera.items():
        worst = c["worst_nfft_over_fft_cpu"]
        print(f"{camera}: worst NFFT/FFT CPU ratio (1 thread, frames of {args.processes} processes) {worst:.1f} (goal "
              f"<= {GOAL_RATIO:.0f}: {'met' if worst <= GOAL_RATIO else 'not met'}; each process alone: "
              f"{', '.join(f'{w:.1f}' for w in c['worst_nfft_over_fft_cpu_per_process'])}); worst eps0 error "
              f"{c['worst_eps0_error_pct']:.2f} % (goal <= 1 %); without CG (points and NUFFTs alone) "
              f"{c['worst_nfft_without_cg_over_fft_cpu']:.1f}; floor (finufft's calls + the fewest CG iterations "
              f"for eps0 within 1 %) {c['floor_over_fft_cpu'][0]:.1f}-{c['floor_over_fft_cpu'][1]:.1f}; 2 processes: "
              f"{c['two_process_wall_ms_per_frame']:.2f} ms wall per frame (FFT + NFFT range features)")
    sphere = sphere_experiment.summary(sphere_experiment.run(Intrinsics(), FeatureConfig(**cfg)),
                                       cfg["equivalence_range_m"])
    print(f"sphere experiment (tofd experiment sphere): NFFT eps0 spread {100 * sphere['nfft_eps0_spread']:.2f} % "
          f"over {sphere_experiment.DISTANCES_M[0]:g}-{sphere_experiment.DISTANCES_M[-1]:g} m (goal <= 2 %)")
    apex = sphere_apex_eps0(FeatureConfig(**cfg))
    values = [v for vs in apex.values() for v in vs]
    spread = max(values) / min(values) - 1
    print(f"cross-camera: NFFT eps0 at a 0.1 m sphere's apex, {len(CAMERAS)} cameras x "
          f"{', '.join(f'{d:g}' for d in SPHERE_CHECK_M)} m: spread {100 * spread:.2f} % (goal <= 2 %)")
    first = per_camera[args.cameras[0]]
    write_json(args.out, {"about": ABOUT, "machine": platform.platform(), "cpu_count": mp.cpu_count(),
                          "repeats": args.repeats,
                          "feature_config": cfg, "face_depth_margin_m": FACE_DEPTH_M,
                          "cameras": {c: CAMERAS[c].to_dict() for c in args.cameras}, "rows": rows,
                          "per_camera": per_camera,
                          "two_process_wall_ms_per_frame": first["two_process_wall_ms_per_frame"],
                          "worst_nfft_over_fft_cpu": first["worst_nfft_over_fft_cpu"],
                          "worst_nfft_over_fft_cpu_per_process": first["worst_nfft_over_fft_cpu_per_process"],
                          "goal_nfft_over_fft": GOAL_RATIO,
                          "sphere_nfft_eps0_spread_pct": 100 * sphere["nfft_eps0_spread"],
                          "cross_camera_apex_eps0_m2": {"distances_m": list(SPHERE_CHECK_M), "values": apex,
                                                        "spread_pct": 100 * spread}})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
