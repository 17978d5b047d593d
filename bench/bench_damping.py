"""Benchmark: the NFFT damping's bias on eps0, against the analytic value on a paraboloid.

A paraboloid z = z0 + (x^2 + y^2) / (2 R) (R = 0.1 m, a disc of radius 0.1 m about its apex, on the optical axis,
exact range by ray intersection) has the Laplacian 2/R everywhere. The filter C0 = A(rho) goes as
e rho^2 / rho0^2 near rho = 0 and a quadratic surface's spectrum sits at k = 0, so at the apex
c0 = -(e / (2 pi rho0)^2) 2/R and eps0 = ((2/R) e / (2 pi rho0)^2)^2 exactly (the disc's rim is 15 impulse-response
widths away). Per camera, apex distance and FeatureConfig.damping: the NFFT eps0 at the apex over that value, minus
1 (percent), and the CG iterations; "converged": the default damping with CG to a 1e-9 residual in double
precision, which separates the damping's bias from the solver's stopping error.
Prints a table and writes JSON (bench/results/bench_damping.json or --out).

    .venv/bin/python bench/bench_damping.py [--out PATH]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import platform
from pathlib import Path

import numpy as np
from cameras import CAMERAS
from report import write_json

import tofd
from tofd.drivers.intrinsics import Intrinsics

RADIUS_M = 0.1  # curvature radius of the paraboloid at its apex
DISC_M = 0.1  # radius of the disc kept about the apex
DISTANCES_M = (0.35, 0.5, 0.7, 0.9)
DAMPINGS = (1e-2, 3e-3, 1e-3)
CONVERGED = {"cg_tolerance": 1e-9, "cg_max_iterations": 3000, "cg_precision": "double", "nufft_eps": 1e-9}


def paraboloid(camera: Intrinsics, apex_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(range_m, mask) of z = apex + (x^2 + y^2) / (2 R) seen by `camera`, the disc x^2 + y^2 < DISC_M^2."""
    rays = camera.unit_rays()
    a = (rays[..., 0] ** 2 + rays[..., 1] ** 2) / (2 * RADIUS_M)
    rz = rays[..., 2]
    with np.errstate(invalid="ignore"):
        t = 2 * apex_m / (rz + np.sqrt(rz**2 - 4 * a * apex_m))  # the nearer root of a t^2 - rz t + apex = 0
        points = rays * t[..., None]
        mask = np.isfinite(t) & (np.hypot(points[..., 0], points[..., 1]) < DISC_M)
    return np.where(mask, t, np.nan), mask


def analytic_eps0(cfg: tofd.FeatureConfig) -> float:
    return float(((2 / RADIUS_M) * math.e / (2 * math.pi * cfg.tuning_frequency_per_m) ** 2) ** 2)


def rows() -> list[dict]:
    out = []
    for label in ("sr3000", "640x576"):
        camera = CAMERAS[label]
        apex = (int(round(camera.cy)), int(round(camera.cx)))
        for d in DISTANCES_M:
            range_m, mask = paraboloid(camera, d)
            row: dict = {"camera": label, "distance_m": d}
            settings = {f"damping_{damping:g}": tofd.FeatureConfig(damping=damping) for damping in DAMPINGS}
            settings["converged"] = dataclasses.replace(tofd.FeatureConfig(), **CONVERGED)
            for name, cfg in settings.items():
                try:
                    result = tofd.FeaturePlan(camera, cfg).eccentricities(range_m, mask=mask)
                except tofd.SamplingError:
                    row[f"{name}_bias_pct"], row[f"{name}_iterations"] = None, None
                    continue
                row[f"{name}_bias_pct"] = 100 * (float(result.eps0[apex]) / analytic_eps0(cfg) - 1)
                row[f"{name}_iterations"] = result.iterations
            out.append(row)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_damping.json"))
    args = parser.parse_args()
    table = rows()
    biases = [r["damping_0.01_bias_pct"] for r in table if r["damping_0.01_bias_pct"] is not None]
    results = {"about": __doc__.split("\n\n")[0], "machine": platform.machine(), "numpy": np.__version__,
               "radius_m": RADIUS_M, "default_damping": tofd.FeatureConfig().damping,
               "default_bias_pct_range": [min(biases), max(biases)], "rows": table}
    print("NFFT eps0 at a paraboloid's apex against the analytic value: bias % (CG iterations)")
    for row in table:
        cells = [f"{name} {row[f'{name}_bias_pct']:+.2f} ({row[f'{name}_iterations']})"
                 for name in [*(f"damping_{d:g}" for d in DAMPINGS), "converged"]
                 if row[f"{name}_bias_pct"] is not None]
        print(f"  {row['camera']:8s} {row['distance_m']:.2f} m: " + "  ".join(cells))
    write_json(args.out, results)


if __name__ == "__main__":
    main()
