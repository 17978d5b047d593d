"""Choose segmentation/feature/box parameters by leave-one-subject-out cross-validation on the TRAINING subjects.

The subjects are tofd.lab.faces.CV_SUBJECTS: the training subjects plus two variants (forward chin, flatter
nose); the test subject of the default split (TEST_SUBJECTS) is never rendered here. Each fold
mirrors the paper's protocol inside the training subjects: learn the boxes on two subjects at the training
distance (0.60 m), evaluate on the held-out third one at the test distances (0.35-0.70 m). Per grid point the
features are computed once per frame and shared by the folds; the score is the mean EER over the folds.

    /work/venv/bin/python bench/tune_detector.py [--grid default|quick] [--frames 36] [--out PATH]

Prints one line per grid point (mean EER % of the four variants, worst fold of NFFT range in brackets) and
writes JSON (bench/results/tune_detector.json by default). Takes ~5 s per grid point on 2 workers.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time
from pathlib import Path

import numpy as np
from report import write_json

from tofd.algorithm.detector import VARIANTS, Candidates
from tofd.config import Config
from tofd.lab.conditions import CONDITIONS, TRAIN_CONDITION
from tofd.lab.evaluation import evaluate_model, extract_samples, train_model
from tofd.lab.faces import CV_SUBJECTS, TEST_DISTANCES_M, TRAIN_DISTANCES_M, render_frames

GRIDS = {
    "quick": {"quantile": [0.05], "border_margin_m": [0.006], "front_depth_m": [0.001]},  # the current defaults
    "front": {"quantile": [0.05], "border_margin_m": [0.006],
              "front_depth_m": [0.0, 0.0005, 0.001, 0.0015, 0.002, 0.003, 0.005, 0.008]},
    "front_noise": {"quantile": [0.05], "border_margin_m": [0.006], "front_depth_m": [0.001],
                    "front_noise_factor": [0.0, 0.25, 0.5, 0.75, 1.0, 1.5]},
    "plane_iter": {"plane_iterations": [2, 4, 8], "plane_depth_m": [0.04, 0.05], "quantile": [0.05],
                   "border_margin_m": [0.006], "front_depth_m": [0.001]},
    "plane_fine": {"plane_iterations": [1, 2, 3], "plane_depth_m": [0.03, 0.04], "depth_margin_m": [0.025, 0.03],
                   "quantile": [0.05], "border_margin_m": [0.006]},
    "damping": {"damping": [0.003, 0.01, 0.03, 0.1, 0.3], "quantile": [0.05], "border_margin_m": [0.006],
                "front_depth_m": [0.001]},
    "nfft_grid": {"grid_size": [64, 72, 80], "quantile": [0.05], "border_margin_m": [0.006], "front_depth_m": [0.001]},
    "band": {"tuning_frequency_per_m": [20.0, 25.0, 30.0, 35.0], "lowpass_sigma_per_m": [30.0, 40.0, 50.0, 70.0],
             "quantile": [0.05], "border_margin_m": [0.006]},
    "band_noise": {"tuning_frequency_per_m": [25.0, 30.0, 35.0], "grid_size": [64, 72], "lowpass_sigma_per_m": [50.0],
                   "quantile": [0.05], "border_margin_m": [0.006], "front_depth_m": [0.001]},  # with --condition
    "band2": {"tuning_frequency_per_m": [35.0, 40.0, 45.0], "lowpass_sigma_per_m": [50.0, 70.0],
              "quantile": [0.05], "border_margin_m": [0.006]},
    "box": {"quantile": [0.02, 0.05, 0.1], "positive_radius_m": [0.003, 0.005, 0.008],
            "border_margin_m": [0.004, 0.006, 0.008, 0.01]},
    "plane": {"plane_iterations": [0, 2], "plane_depth_m": [0.04, 0.06], "depth_margin_m": [0.025, 0.035],
              "quantile": [0.05], "border_margin_m": [0.006]},
    "shaped": {"depth_margin_m": [0.02, 0.025, 0.03, 0.035], "quantile": [0.05],
               "border_margin_m": [0.004, 0.006, 0.008, 0.01, 0.012, 0.015]},
    "border": {"head_height_m": [0.0, 0.18], "depth_margin_m": [0.035, 0.05], "quantile": [0.05],
               "border_margin_m": [0.0, 0.004, 0.008, 0.01, 0.012, 0.015, 0.02]},
    "chin": {"depth_margin_m": [0.03, 0.035, 0.045], "quantile": [0.05],
             "border_margin_m": [0.0, 0.004, 0.008, 0.01, 0.012, 0.015, 0.02]},
    "chin_fine": {"depth_margin_m": [0.02, 0.025, 0.03, 0.035], "quantile": [0.05],
                  "border_margin_m": [0.004, 0.006, 0.008, 0.01]},
    "default": {"tuning_frequency_per_m": [10.0, 15.0, 20.0, 25.0, 30.0, 40.0],
                "depth_margin_m": [0.04, 0.05, 0.06, 0.08, 0.10], "quantile": [0.05]},
    "wide": {"tuning_frequency_per_m": [8.0, 10.0, 13.0, 16.0, 20.0], "lowpass_sigma_per_m": [50.0],
             "depth_margin_m": [0.06, 0.08, 0.10], "quantile": [0.05, 0.1]},
    "fine": {"tuning_frequency_per_m": [20.0, 25.0, 30.0, 40.0], "depth_margin_m": [0.04, 0.05, 0.06],
             "quantile": [0.05]},
    "finer": {"tuning_frequency_per_m": [30.0, 35.0, 40.0, 50.0], "depth_margin_m": [0.03, 0.035, 0.04, 0.045],
              "quantile": [0.05]},
}
SEGMENTATION_KEYS = ("depth_margin_m", "range_percentile", "median_px", "morphology_px", "head_height_m",
                     "plane_iterations", "plane_depth_m", "plane_max_tilt_deg")
CANDIDATE_KEYS = ("border_margin_m", "front_depth_m", "front_noise_factor")  # tofd.algorithm.detector.Candidates
BOX_KEYS = ("quantile", "positive_radius_m", *CANDIDATE_KEYS)  # cheap: no feature recomputation


def render_subjects(frames: int, seed: int, condition: str = TRAIN_CONDITION) -> dict[str, dict[str, object]]:
    """Per training subject: `frames` frames at the training distance and 2 * `frames` at the test distances, the
    test frames under the sensor `condition` (tofd.lab.conditions; training always under the training sensor)."""
    out = {}
    for i, name in enumerate(CV_SUBJECTS):
        out[name] = {"train": render_frames((name,), TRAIN_DISTANCES_M, frames, seed + 2 * i),
                     "test": render_frames((name,), TEST_DISTANCES_M, 2 * frames, seed + 2 * i + 1,
                                           model=CONDITIONS[condition])}
    return out


def config_for(point: dict) -> Config:
    cfg = Config()
    seg = {k: v for k, v in point.items() if k in SEGMENTATION_KEYS}
    feat = {k: v for k, v in point.items() if k not in SEGMENTATION_KEYS + BOX_KEYS}
    return dataclasses.replace(cfg, segmentation=dataclasses.replace(cfg.segmentation, **seg),
                               features=dataclasses.replace(cfg.features, **feat))


def cross_validate(data: dict, cfg: Config, box: dict, cache: dict, workers: int) -> dict:
    """EER per variant and fold (held-out subject) for one configuration."""
    key = (cfg.features, cfg.segmentation)
    if key not in cache:
        cache.clear()  # one feature configuration at a time (grids iterate box keys innermost)
        cache[key] = {name: {split: extract_samples(ds, cfg.features, cfg.segmentation, workers)
                             for split, ds in d.items()} for name, d in data.items()}
    samples = cache[key]
    folds = {}
    for held in data:
        train = [s for name in data if name != held for s in samples[name]["train"]]
        candidates = Candidates(**{k: v for k, v in box.items() if k in CANDIDATE_KEYS})
        model = train_model(train, cfg.features, cfg.segmentation, candidates=candidates,
                            **{k: v for k, v in box.items() if k not in CANDIDATE_KEYS})
        res = evaluate_model(model, samples[held]["test"], data[held]["test"].distance_m, candidates=candidates)
        folds[held] = {v: r.overall.eer for v, r in res.items()}
    return folds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", choices=sorted(GRIDS), default="default")
    parser.add_argument("--frames", type=int, default=36, help="frames per subject at 0.60 m (test: twice this)")
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--condition", choices=sorted(CONDITIONS), default=TRAIN_CONDITION,
                        help="sensor condition of the held-out folds' test frames (tofd.lab.conditions)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "tune_detector.json"))
    args = parser.parse_args()

    start = time.monotonic()
    data = render_subjects(args.frames, args.seed, args.condition)
    grid = GRIDS[args.grid]
    keys = [k for k in grid if k not in BOX_KEYS] + [k for k in grid if k in BOX_KEYS]
    rows, cache = [], {}
    print(" ".join(f"{k:>14}" for k in keys) + "  " + " ".join(f"{v:>15}" for v in VARIANTS))
    for values in itertools.product(*(grid[k] for k in keys)):
        point = dict(zip(keys, values, strict=True))
        cfg = config_for(point)
        folds = cross_validate(data, cfg, {k: v for k, v in point.items() if k in BOX_KEYS}, cache, args.workers)
        mean = {v: float(np.mean([f[v] for f in folds.values()])) for v in VARIANTS}
        worst = max(f["nfft_range"] for f in folds.values())
        rows.append({"point": point, "mean_eer": mean, "folds": folds})
        print(" ".join(f"{v:>14g}" for v in values) + "  " + " ".join(f"{100 * mean[v]:>15.1f}" for v in VARIANTS)
              + f"  [{100 * worst:.0f}]", flush=True)
    best = min(rows, key=lambda r: (r["mean_eer"]["nfft_range"], r["mean_eer"]["nfft_range_amp"]))
    print(f"best (mean NFFT range EER, then NFFT range+amp): {best['point']}")
    write_json(args.out, {"protocol": "leave-one-training-subject-out: train 2 subjects at "
                          f"{TRAIN_DISTANCES_M} m, test the third at {TEST_DISTANCES_M} m",
                          "subjects": list(CV_SUBJECTS), "frames_per_subject": args.frames,
                          "test_condition": args.condition,
                          "seed": args.seed, "grid": grid, "rows": rows, "best": best,
                          "seconds": round(time.monotonic() - start, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
