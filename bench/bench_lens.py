"""Benchmark: what the lens model costs. Per camera (the SR3000 pinhole; an Azure Kinect NFOV unbinned lens,
rational_polynomial): building every pixel's unit ray (once per camera, then cached), back-projecting a range
map, pixel_rays of 1000 sub-pixel points and project of 1000 points; the pinhole also against the plain pinhole
formula written out here (the code before lens models), the baseline of the same run.

Prints a table (median ms of --repeats runs) and writes JSON (bench/results/bench_lens.json or --out).

    .venv/bin/python bench/bench_lens.py [--repeats 20] [--out PATH]
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from report import write_json

from tofd.drivers import intrinsics as lens_module
from tofd.drivers.intrinsics import Intrinsics

K4A_NFOV = Intrinsics(640, 576, 504.6076, 504.7325, 332.7811, 348.8297, "rational_polynomial",
                      (0.54794, -0.020971, 2.0558e-05, -7.2104e-05, -0.0026522, 0.88968, 0.08613, -0.01391))
"""The NFOV unbinned depth lens of a real Azure Kinect (tests/data/k4a_calibration.json), rounded."""
CAMERAS = {"sr3000_pinhole": Intrinsics(), "k4a_nfov_rational": K4A_NFOV}


def plain_pinhole_rays(i: Intrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    x, y = (np.asarray(u, np.float64) - i.cx) / i.fx, (np.asarray(v, np.float64) - i.cy) / i.fy
    rays = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def plain_pinhole_project(i: Intrinsics, p: np.ndarray) -> np.ndarray:
    z = p[..., 2]
    return np.stack([i.fx * p[..., 0] / z + i.cx, i.fy * p[..., 1] / z + i.cy], axis=-1)


def median_ms(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


def bench(i: Intrinsics, repeats: int) -> dict[str, float]:
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, i.width - 1, 1000), rng.uniform(0, i.height - 1, 1000)
    range_m = rng.uniform(0.4, 1.5, i.shape)
    points = i.pixel_rays(u, v) * rng.uniform(0.4, 1.5, (1000, 1))
    grid_u, grid_v = np.arange(i.width)[None, :], np.arange(i.height)[:, None]

    def build() -> None:
        lens_module._unit_rays.cache_clear()
        i.unit_rays()

    out = {"unit_rays_build_ms": median_ms(build, max(3, repeats // 4)),
           "backproject_ms": median_ms(lambda: i.backproject(range_m), repeats),
           "pixel_rays_1000_ms": median_ms(lambda: i.pixel_rays(u, v), repeats),
           "project_1000_ms": median_ms(lambda: i.project(points), repeats)}
    if i.is_pinhole:
        out["baseline_unit_rays_build_ms"] = median_ms(lambda: plain_pinhole_rays(i, grid_u, grid_v),
                                                       max(3, repeats // 4))
        out["baseline_pixel_rays_1000_ms"] = median_ms(lambda: plain_pinhole_rays(i, u, v), repeats)
        out["baseline_project_1000_ms"] = median_ms(lambda: plain_pinhole_project(i, points), repeats)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_lens.json")
    args = parser.parse_args()
    results = {name: bench(i, args.repeats) for name, i in CAMERAS.items()}
    pin = results["sr3000_pinhole"]
    for kind in ("unit_rays_build", "pixel_rays_1000", "project_1000"):
        pin[f"{kind}_ratio_to_baseline"] = pin[f"{kind}_ms"] / pin[f"baseline_{kind}_ms"]
    print(f"{'camera':<20} {'rays build':>11} {'backproject':>12} {'pixel_rays':>11} {'project':>9}  (median ms)")
    for name, r in results.items():
        print(f"{name:<20} {r['unit_rays_build_ms']:>11.3f} {r['backproject_ms']:>12.3f} "
              f"{r['pixel_rays_1000_ms']:>11.3f} {r['project_1000_ms']:>9.3f}")
    print("pinhole / plain pinhole formula: " + ", ".join(
        f"{k} {pin[f'{k}_ratio_to_baseline']:.2f}" for k in ("unit_rays_build", "pixel_rays_1000", "project_1000")))
    write_json(args.out, {"repeats": args.repeats, "machine": platform.machine(), "cameras": results})


if __name__ == "__main__":
    main()
