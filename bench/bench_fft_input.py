"""Benchmark: what the FFT path should filter, z-depth or the radial range (FeatureConfig.fft_input).

Two measurements, both input choices in the same run:
- sphere: eps0 at the apex of a 0.1 m sphere on the SR3000 at several distances, by the FFT path on z-depth and on
  range, as a ratio to the NFFT path's (the scale-invariant surface feature; the FFT path reads its grid at the
  equivalence range, so at 0.5 m the z-depth path should agree with it);
- detector: the nose detector trained on rendered SR3000 frames (tofd.render_dataset "train") with each input and
  evaluated on the "test" split: the FFT variants' equal error rate (EER) and share of frames whose nose was found at
  the operating scale. With the bundled segmentation z-depth is measured along the fitted face plane's normal
  (tofd.algorithm.segmentation.Foreground.rotation), which range cannot be; plane_iterations = 0 (the cut along the
  camera's z axis, no rotation) compares the two inputs alone. The lower EER decides FeatureConfig.fft_input's
  default.
Prints a table and writes JSON (bench/results/bench_fft_input.json or --out).

    .venv/bin/python bench/bench_fft_input.py [--train 60] [--test 60] [--workers 1] [--out PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import platform
import time
from pathlib import Path

import numpy as np
from report import write_json

import tofd
from tofd.algorithm.params import FFT_INPUTS
from tofd.config import load_config
from tofd.lab import shapes

SPHERE_DISTANCES_M = (0.35, 0.5, 0.7, 0.9)
RADIUS_M = 0.1
FFT_VARIANTS = ("fft_range", "fft_range_amp")


def sphere_rows() -> list[dict]:
    """Per distance: apex eps0 of the FFT path on each input over the NFFT path's."""
    camera = tofd.Intrinsics()
    apex = (int(round(camera.cy)), int(round(camera.cx)))
    rows = []
    for d in SPHERE_DISTANCES_M:
        range_m = shapes.sphere(camera, d, RADIUS_M).range_m
        nfft = tofd.eccentricities(range_m, camera).eps0[apex]
        row: dict = {"distance_m": d, "nfft_eps0": float(nfft)}
        for kind in FFT_INPUTS:
            fft = tofd.eccentricities(range_m, camera, method="fft", config=tofd.FeatureConfig(fft_input=kind))
            row[f"fft_{kind}_over_nfft"] = float(fft.eps0[apex] / nfft)
        rows.append(row)
    return rows


def detector_rows(train_frames: int, test_frames: int, workers: int) -> list[dict]:
    """Per input: the FFT variants' EER and found share on the test split, trained on the train split."""
    train = tofd.render_dataset("train", frames=train_frames, seed=1)
    test = tofd.render_dataset("test", frames=test_frames, seed=2)
    base = load_config()
    rows = []
    for kind, plane_iterations in itertools.product(FFT_INPUTS, (base.segmentation.plane_iterations, 0)):
        cfg = dataclasses.replace(base, features=dataclasses.replace(base.features, fft_input=kind),
                                  segmentation=dataclasses.replace(base.segmentation,
                                                                   plane_iterations=plane_iterations))
        start = time.perf_counter()
        model = tofd.train_model(train, config=cfg, workers=workers)
        results = tofd.evaluate_model(model, test, config=cfg, workers=workers)
        row: dict = {"fft_input": kind, "plane_iterations": plane_iterations, "seconds": time.perf_counter() - start}
        for variant in FFT_VARIANTS:
            row[f"{variant}_eer"] = float(results[variant].overall.eer)
            row[f"{variant}_found"] = float(results[variant].answers.found)
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=int, default=60, help="rendered training frames")
    parser.add_argument("--test", type=int, default=60, help="rendered test frames")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_fft_input.json"))
    args = parser.parse_args()
    sphere = sphere_rows()
    detector = detector_rows(args.train, args.test, args.workers)
    best = min(detector, key=lambda r: r["fft_range_eer"])
    best = f"{best['fft_input']} (plane_iterations {best['plane_iterations']})"
    results = {"about": __doc__.split("\n\n")[0], "machine": platform.machine(), "numpy": np.__version__,
               "train_frames": args.train, "test_frames": args.test, "sphere": sphere, "detector": detector,
               "lower_fft_range_eer": best}
    print("sphere apex eps0, FFT path over NFFT path (SR3000, R = 0.1 m)")
    for row in sphere:
        print(f"  {row['distance_m']:.2f} m: z {row['fft_z_over_nfft']:.3f}  range {row['fft_range_over_nfft']:.3f}")
    print(f"detector, {args.train} train / {args.test} test rendered frames")
    for row in detector:
        print("  " + "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    print(f"lower fft_range EER: {best}")
    write_json(args.out, results)


if __name__ == "__main__":
    main()
