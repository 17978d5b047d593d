"""Benchmark: the public functions on a stream of frames against what the same work costs done by hand.

At one camera geometry (default 640x576, the Azure Kinect's NFOV), frame after frame in one process, on two scenes:
rendered, noisy frames of a face (segmented as the pipeline does, so the FFT covers the face's box) and a whole
0.1 m sphere (a larger box) at several distances:
- fft_public: `tofd.eccentricities(method="fft")` (its cached plan reused, float64 results);
- fft_scipy: the baseline, a plain scipy rfft2 of the face's box padded as the FFT path pads it, the three
  eccentricity filters (made beforehand) multiplied in and three irfft2, nothing else;
- fft_setup_per_call: FFTFeatures made anew for every frame (what a call cost before plans were kept);
- nfft_public: `tofd.eccentricities(method="nfft")`;
- nfft_pipeline: the pipeline's own engine (NFFTFeatures, made once) on the same frames and masks;
- nfft_setup_per_call: NFFTFeatures made anew for every frame.
CPU milliseconds per frame (thread time: meaningful while other processes share the cores), median over the frames
and repeats, the variants interleaved frame by frame. Ratios: fft_public / fft_scipy (goal <= 3) and nfft_public /
nfft_pipeline (goal <= 1.5). First call: a fresh interpreter's first `tofd.eccentricities` per method, wall
seconds, with numba's on-disk cache already written (a run before it) and, for the record, the process's import.
The same without numba's disk cache (an empty NUMBA_CACHE_DIR): what the first call on a machine compiles.
Prints a table and writes JSON (bench/results/bench_api_stream.json or --out).

    .venv/bin/python bench/bench_api_stream.py [--camera 640x576] [--frames 6] [--repeats 5] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.fft as sfft
from cameras import CAMERAS
from report import write_json

import tofd
from tofd.algorithm.features import FFTFeatures, NFFTFeatures
from tofd.algorithm.features.fft import fast_length
from tofd.algorithm.features.transfer import pixel_frequencies_per_m, transfer_functions
from tofd.algorithm.params import FeatureConfig, SegmentationConfig
from tofd.algorithm.segmentation import segment
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes

GOAL_FFT, GOAL_NFFT = 3.0, 1.5
DISTANCES_M = (0.45, 0.5, 0.55, 0.6, 0.65, 0.7)
FIRST_CALL = """
import json, sys, time
import numpy as np
t0 = time.perf_counter()
import tofd
t1 = time.perf_counter()
camera = tofd.Intrinsics.from_dict(json.loads(sys.argv[1]))
plane = tofd.range_from_depth(np.full(camera.shape, 0.5), camera, scale=1.0)
rows, cols = np.indices(camera.shape)
disc = np.hypot(rows - camera.cy, cols - camera.cx) < 0.1 * camera.fx
t2 = time.perf_counter()
tofd.eccentricities(plane, camera, mask=disc, method=sys.argv[2])
t3 = time.perf_counter()
print(t1 - t0, t3 - t2)
"""


def frames(intrinsics: Intrinsics, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(range_m, mask) of `count` rendered noisy face frames at DISTANCES_M (cycled), segmented by default."""
    face, seg = load_face("lee_perry_smith"), SegmentationConfig()
    out = []
    for i in range(count):
        pose = Pose(distance_m=DISTANCES_M[i % len(DISTANCES_M)], yaw_deg=10.0 * (i % 3 - 1), pitch_deg=5.0)
        r = render_face(face, pose, intrinsics, np.random.default_rng(i))
        range_m = r.range_m.astype(np.float64)
        out.append((range_m, segment(range_m, r.amplitude, seg, intrinsics)))
    return out


def scipy_baseline(intrinsics: Intrinsics, cfg: FeatureConfig, mask: np.ndarray
                   ) -> Callable[[np.ndarray], np.ndarray]:
    """A plain scipy FFT of the three filters on the mask's box, padded as the FFT path pads it (filters made now)."""
    padding = FFTFeatures(intrinsics, cfg).padding_px
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    h, w = rows[-1] + 1 - rows[0], cols[-1] + 1 - cols[0]
    shape = (fast_length(h + 2 * padding[0], 10**6), fast_length(w + 2 * padding[1], 10**6))
    kx, ky = pixel_frequencies_per_m(sfft.rfftfreq(shape[1])[None, :], sfft.fftfreq(shape[0])[:, None], intrinsics,
                                     cfg.equivalence_range_m)
    filters = transfer_functions(kx, ky, cfg.tuning_frequency_per_m, cfg.lowpass_sigma_per_m)
    window = (slice(padding[0], padding[0] + h), slice(padding[1], padding[1] + w))

    def run(range_m: np.ndarray) -> np.ndarray:
        buf = np.zeros(shape)
        buf[window] = np.nan_to_num(range_m[box])
        spectrum = sfft.rfft2(buf, workers=1)
        return np.stack([sfft.irfft2(spectrum * f, s=shape, workers=1)[window] for f in filters])

    return run


def cpu_ms(run: Callable[[np.ndarray, np.ndarray, int], object], range_m: np.ndarray, mask: np.ndarray,
           i: int) -> float:
    """CPU milliseconds (this thread) of run(range_m, mask, i)."""
    start = time.thread_time()
    run(range_m, mask, i)
    return (time.thread_time() - start) * 1e3


def first_call_s(intrinsics: Intrinsics, method: str, cache_dir: str | None = None) -> tuple[float, float]:
    """(import seconds, first call seconds) of a fresh interpreter, wall time; cache_dir: numba's cache directory
    (an empty one: everything compiled anew), None: its default, the package's __pycache__."""
    env = dict(os.environ, **({"NUMBA_CACHE_DIR": cache_dir} if cache_dir else {}))
    out = subprocess.run([sys.executable, "-c", FIRST_CALL, json.dumps(intrinsics.to_dict()), method],
                         capture_output=True, text=True, check=True, timeout=600, env=env).stdout.split()
    return float(out[0]), float(out[1])


def time_scene(intrinsics: Intrinsics, cfg: FeatureConfig, stream: list[tuple[np.ndarray, np.ndarray]],
               repeats: int) -> dict:
    """Median CPU ms per frame of every variant on one scene's frames, and the ratios."""
    engine = NFFTFeatures(intrinsics, cfg)
    baselines = [scipy_baseline(intrinsics, cfg, mask) for _, mask in stream]
    variants: dict[str, Callable[[np.ndarray, np.ndarray, int], object]] = {
        "fft_public": lambda r, m, i: tofd.eccentricities(r, intrinsics, mask=m, method="fft"),
        "fft_scipy": lambda r, m, i: baselines[i](r),
        "nfft_public": lambda r, m, i: tofd.eccentricities(r, intrinsics, mask=m, method="nfft"),
        "nfft_pipeline": lambda r, m, i: engine.range_features(r, m),
    }
    per_call = {"fft_setup_per_call": lambda r, m, i: FFTFeatures(intrinsics, cfg).range_features(r, m),
                "nfft_setup_per_call": lambda r, m, i: NFFTFeatures(intrinsics, cfg).range_features(r, m)}
    for run in variants.values():  # warm: plans made, numba loaded
        run(*stream[0], 0)
    times: dict[str, list[float]] = {name: [] for name in (*variants, *per_call)}
    for repeat in range(repeats):
        for i, (range_m, mask) in enumerate(stream):
            for name, run in variants.items():
                times[name].append(cpu_ms(run, range_m, mask, i))
            if repeat == 0:  # a set-up per call is slow: one pass is enough
                for name, run in per_call.items():
                    times[name].append(cpu_ms(run, range_m, mask, i))
    median = {name: float(np.median(t)) for name, t in times.items()}
    return {"cpu_median_ms": median,
            "fft_public_over_scipy": median["fft_public"] / median["fft_scipy"],
            "fft_setup_per_call_over_scipy": median["fft_setup_per_call"] / median["fft_scipy"],
            "nfft_public_over_pipeline": median["nfft_public"] / median["nfft_pipeline"],
            "nfft_setup_per_call_over_pipeline": median["nfft_setup_per_call"] / median["nfft_pipeline"],
            "foreground_pixels_median": int(np.median([m.sum() for _, m in stream]))}


def spheres(intrinsics: Intrinsics, count: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(range_m, mask) of a 0.1 m sphere, whole, at DISTANCES_M (cycled): a larger box than a segmented face's."""
    out = []
    for i in range(count):
        s = shapes.sphere(intrinsics, DISTANCES_M[i % len(DISTANCES_M)], 0.1)
        out.append((s.range_m, s.mask))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", default="640x576", choices=sorted(CAMERAS))
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_api_stream.json"))
    args = parser.parse_args()
    intrinsics, cfg = CAMERAS[args.camera], FeatureConfig()
    scenes = {"face": frames(intrinsics, args.frames), "sphere": spheres(intrinsics, args.frames)}
    rows = [{"scene": name, **time_scene(intrinsics, cfg, stream, args.repeats)} for name, stream in scenes.items()]
    first = {method: first_call_s(intrinsics, method) for method in ("fft", "nfft")}
    with tempfile.TemporaryDirectory() as empty:
        compiling = first_call_s(intrinsics, "nfft", empty)
    results = {
        "about": __doc__.split("\n\n")[0], "camera": args.camera, "frames": args.frames, "repeats": args.repeats,
        "machine": platform.machine(), "python": platform.python_version(), "numpy": np.__version__,
        "goals": {"fft_public_over_scipy": GOAL_FFT, "nfft_public_over_pipeline": GOAL_NFFT},
        "fft_public_over_scipy_worst": max(r["fft_public_over_scipy"] for r in rows),
        "nfft_public_over_pipeline_worst": max(r["nfft_public_over_pipeline"] for r in rows),
        "fresh_process_s": {m: {"import": v[0], "first_call": v[1]} for m, v in first.items()},
        "fresh_process_nfft_compiling_s": compiling[1],
        "rows": rows,
    }
    for row in rows:
        print(f"{args.camera}, {args.frames} {row['scene']} frames x {args.repeats} "
              f"({row['foreground_pixels_median']} foreground pixels): CPU ms per frame (median)")
        for name, value in row["cpu_median_ms"].items():
            print(f"  {name:22s} {value:9.2f}")
        print(f"  fft public / scipy      {row['fft_public_over_scipy']:.2f}  (goal <= {GOAL_FFT}; set-up per call: "
              f"{row['fft_setup_per_call_over_scipy']:.0f})")
        print(f"  nfft public / pipeline  {row['nfft_public_over_pipeline']:.2f}  (goal <= {GOAL_NFFT}; set-up per "
              f"call: {row['nfft_setup_per_call_over_pipeline']:.1f})")
    print("fresh process, first call (s): " + json.dumps(results["fresh_process_s"]))
    print(f"fresh process, first NFFT call without numba's disk cache: {compiling[1]:.1f} s")
    write_json(args.out, results)


if __name__ == "__main__":
    main()
