"""Robustness matrix of a nose model: held-out identities x unseen sensor conditions x nose distances.

Drives tofd.lab.robustness (conditions: tofd.lab.conditions; identities: tofd.lab.faces.HOLDOUT_SUBJECTS, never
trained or tuned on, or --subjects). Prints, per variant, a condition x distance table of the worst cell over subjects
and the worst cell overall; writes everything as JSON.

    .venv/bin/python bench/robustness.py [--model config/nose_model.json] [--frames 60] [--conditions all]
                                         [--distances 0.6,0.65,0.7] [--variants nfft_range,fft_range] [--seed 1000]
    .venv/bin/python bench/robustness.py --subjects mp_bignose,lps_smallnose \
                                         --out bench/results/robustness_old_holdout.json
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from report import add_model_arguments, shown_path, write_json

from tofd.algorithm.detector import VARIANTS, Candidates, Margin, load_model
from tofd.config import load_config
from tofd.lab.conditions import parse_conditions
from tofd.lab.faces import HOLDOUT_SUBJECTS, OLD_HOLDOUT_SUBJECTS, parse_subjects
from tofd.lab.robustness import MATRIX_VARIANTS, MatrixSpec, condition_table, run_matrix, summarize

ABOUT = ("Shipped model, held-out identities (never trained or tuned on) x sensor conditions training never saw "
         "(tofd.lab.conditions) x nose distance, yaw +-30 deg, pitch +-15 deg; per cell EER, found/wrong at the "
         "operating scale with the config's margin test, and the misses by why: the nose scored best but was not "
         "reported, was outranked, or had no candidate pixel.")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=60, help="frames per subject, condition and distance")
    parser.add_argument("--conditions", default="all", help="comma-separated names or 'all' (tofd.lab.conditions)")
    parser.add_argument("--distances", default=None, metavar="M,M,...",
                        help="nose distances in metres (default: the test distances, tofd.lab.faces)")
    parser.add_argument("--variants", default=",".join(MATRIX_VARIANTS),
                        help=f"comma-separated detector variants (of {', '.join(VARIANTS)})")
    parser.add_argument("--subjects", default=",".join(HOLDOUT_SUBJECTS),
                        help="identities, comma-separated (default: the held-out ones; "
                             f"{','.join(OLD_HOLDOUT_SUBJECTS)}: the old held-out variants)")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "robustness.json"))
    args = parser.parse_args()
    try:
        spec = MatrixSpec(conditions=parse_conditions(args.conditions), frames=args.frames, seed=args.seed)
    except ValueError as exc:
        raise SystemExit(f"robustness: --conditions: {exc}") from None
    try:
        subjects = parse_subjects(args.subjects)
    except ValueError as exc:
        raise SystemExit(f"robustness: --subjects: {exc}") from None
    spec = dataclasses.replace(spec, subjects=subjects)
    variants = tuple(args.variants.split(","))
    if unknown := [v for v in variants if v not in VARIANTS]:
        raise SystemExit(f"robustness: --variants: unknown {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    if args.distances:
        try:
            spec = dataclasses.replace(spec, distances_m=tuple(float(d) for d in args.distances.split(",")))
        except ValueError:
            raise SystemExit(f"robustness: --distances: {args.distances!r} is not a list of metres") from None

    start = time.monotonic()
    cfg = load_config(args.config)
    model = load_model(args.model)
    cells = run_matrix(model, spec, cfg.features, cfg.segmentation,
                       Candidates.from_config(cfg.detector, cfg.segmentation), Margin.from_config(cfg.detector),
                       workers=args.workers, variants=variants,
                       progress=lambda what: print(f"  done {what} ({time.monotonic() - start:.0f} s)", flush=True))
    summary = summarize(cells)
    for variant, s in summary.items():
        print(condition_table(cells, variant))
        print(f"{variant}: mean EER {100 * s['mean']['eer']:.1f} %, found {100 * s['mean']['found']:.1f} %, "
              f"wrong {100 * s['mean']['wrong']:.1f} %; cells meeting the goal {s['cells_meeting_goal']}/{s['cells']}")
        print(f"  misses: the nose scored best but was not reported {100 * s['mean']['rejected']:.1f} %,"
              f" outranked {100 * s['mean']['outranked']:.1f} %, no candidate nose pixel "
              f"{100 * s['mean']['no_candidate']:.1f} % of frames (mean over cells)")
        for key in ("worst_eer", "worst_found", "worst_wrong"):
            c = s[key]
            print(f"  {key}: {c['condition']} {c['subject']} {c['distance_m']:.2f} m: EER {100 * c['eer']:.1f} %, "
                  f"found {100 * c['found']:.1f} %, wrong {100 * c['wrong']:.1f} % ({c['frames']} frames)")
    write_json(args.out, {"title": "Robustness matrix (bench/robustness.py)", "about": ABOUT,
                          "model": shown_path(args.model),
                          "model_training": model.training, "spec": dataclasses.asdict(spec),
                          "summary": summary, "cells": [dataclasses.asdict(c) for c in cells],
                          "seconds": round(time.monotonic() - start, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
