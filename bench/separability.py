"""Separability bound: where the robustness matrix fails, could any detector on range (eps0, eps2) meet the goal?

Per cell (sensor condition x subject x nose distance, rendered as the matrix renders them): the shipped model's
per-image EER beside two optimistic bounds fitted to the cell's own frames (tofd.lab.separability): the best box and
the pixels' likelihood ratio, for NFFT and FFT range features at several tunings rho0 of the filter band (the model
only at the config's rho0, which it was trained for). Prints a table and writes JSON.

    .venv/bin/python bench/separability.py [--frames 120] [--rho0 20,25,30,40] [--distances 0.5,0.6,0.65,0.7]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from report import add_model_arguments, shown_path, write_json

from tofd.algorithm.detector import Candidates, Margin, load_model
from tofd.config import load_config
from tofd.lab.conditions import CONDITIONS, parse_conditions
from tofd.lab.evaluation import (
    NOSE_RADIUS_M,
    PixelTable,
    distance_bins,
    evaluate_model,
    extract_samples,
    has_nose,
)
from tofd.lab.faces import HOLDOUT_SUBJECTS, TRAIN_SUBJECTS, render_frames
from tofd.lab.robustness import GOAL_EER, MATRIX_VARIANTS
from tofd.lab.separability import best_box_eer, likelihood_ratio_eer

ABOUT = ("Optimistic bounds on the per-image EER of range-only features: the best box and the likelihood ratio, "
         "both fitted to the cell's own frames (tofd.lab.separability), at several rho0; beside them the shipped "
         "model's EER on the same frames. A bound above the goal: no detector on these features meets it there.")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=120, help="frames per cell")
    parser.add_argument("--rho0", default="20,25,30,40", help="tunings of the filter band, cycles/m")
    parser.add_argument("--conditions", default="noise_x2,dark_face,train_sensor")
    parser.add_argument("--subjects", default=",".join((*HOLDOUT_SUBJECTS, TRAIN_SUBJECTS[0])))
    parser.add_argument("--distances", default="0.5,0.6,0.65,0.7", help="nose distances, metres")
    parser.add_argument("--seed", type=int, default=3000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "separability.json"))
    args = parser.parse_args()
    try:
        conditions = parse_conditions(args.conditions)
        rho0s = [float(r) for r in args.rho0.split(",")]
        distances = tuple(float(d) for d in distance_bins([float(d) for d in args.distances.split(",")]))
    except ValueError as exc:
        raise SystemExit(f"separability: {exc}") from None
    subjects = tuple(args.subjects.split(","))

    start = time.monotonic()
    cfg = load_config(args.config)
    model = load_model(args.model)
    candidates = Candidates.from_config(cfg.detector, cfg.segmentation)
    rows = []
    for ci, condition in enumerate(conditions):
        for si, subject in enumerate(subjects):
            ds = render_frames((subject,), distances, args.frames * len(distances), args.seed + 100 * ci + si,
                               model=CONDITIONS[condition])
            bins = distance_bins(ds.distance_m)
            cells = {d: {"condition": condition, "subject": subject, "distance_m": d} for d in distances}
            for rho0 in rho0s:
                features = cfg.features.tuned_to(rho0)
                samples = extract_samples(ds, features, cfg.segmentation, args.workers)
                model_eer = {}
                if rho0 == cfg.features.tuning_frequency_per_m:
                    results = evaluate_model(model, samples, ds.distance_m, NOSE_RADIUS_M, candidates,
                                             Margin.from_config(cfg.detector))
                    model_eer = {v: {d: r.eer for d, r in results[v].per_distance.items()} for v in MATRIX_VARIANTS}
                for d in distances:
                    here = [s for s, b in zip(samples, bins, strict=True) if b == d]
                    with_nose = has_nose(here, NOSE_RADIUS_M)
                    for v in MATRIX_VARIANTS:
                        table = PixelTable(here, v, NOSE_RADIUS_M, candidates)
                        cells[d][f"{v}_box_{rho0:g}"] = best_box_eer(table, with_nose)
                        cells[d][f"{v}_ratio_{rho0:g}"] = likelihood_ratio_eer(table, with_nose)
                        if model_eer:
                            cells[d][f"{v}_model"] = model_eer[v][d]
            rows.extend(cells.values())
            print(f"  done {condition} {subject} ({time.monotonic() - start:.0f} s)", flush=True)

    print("NFFT range EER %: best box per rho0, best likelihood ratio over rho0, the shipped model")
    print(f"{'cell':<34}" + "".join(f"{f'box {r:g}':>9}" for r in rho0s) + f"{'ratio':>9}{'model':>9}")
    for r in rows:
        name = f"{r['condition']} {r['subject']} {r['distance_m']:.2f}"
        best_ratio = min(r[f"nfft_range_ratio_{x:g}"] for x in rho0s)
        print(f"{name:<34}" + "".join(f"{100 * r[f'nfft_range_box_{x:g}']:9.1f}" for x in rho0s)
              + f"{100 * best_ratio:9.1f}{100 * r.get('nfft_range_model', np.nan):9.1f}")
    beyond = [r for r in rows if min(min(r[f"nfft_range_box_{x:g}"], r[f"nfft_range_ratio_{x:g}"])
                                     for x in rho0s) > GOAL_EER]
    print(f"cells where no box and no likelihood ratio on NFFT range features, at any rho0, reaches EER <= "
          f"{100 * GOAL_EER:g} % even on the cell's own frames: {len(beyond)} of {len(rows)}")
    write_json(args.out, {"title": "Separability bound (bench/separability.py)", "about": ABOUT,
                          "model": shown_path(args.model), "frames_per_cell": args.frames, "seed": args.seed,
                          "rho0_per_m": rho0s, "goal_eer": GOAL_EER,
                          "cells_beyond_goal": [{k: r[k] for k in ("condition", "subject", "distance_m")}
                                                for r in beyond],
                          "rows": rows, "seconds": round(time.monotonic() - start, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
