"""Beyond one box: NFFT scorers learned on many face shapes, measured on identities never trained or tuned on.

Training: the shipped model's subjects plus tofd.lab.faces.SHAPE_TRAIN_SUBJECTS at 0.45-0.70 m; test: static poses
of HOLDOUT_SUBJECTS at --distance (SR3000 geometry, the training sensor). With --train-mesh only the identities on
that base mesh are trained on and only the held-out ones on the other mesh tested: a head never seen in training.
Features: the NFFT eccentricities of the range (and amplitude) at the configured band and at a second, coarser
band in metres (--band2, per metre; its low-pass sigma scaled alike). Scorers, each on the candidate pixels
(config's candidate rule):
- box: the paper's box (learn_box, then shape_box on the training frames), range at the configured band;
- box_2band: the same box on the range at both bands;
- ellipsoid, ellipsoid_2band, ellipsoid_2band_amp: the Gaussian fit of the nose pixels (tofd.lab.ellipsoid) on the
  range at one band, at both, and at both plus the amplitude at the configured band.
Per scorer: the per-image ROC's EER overall and per identity, and the answers at the training frames' operating
scale (tofd.lab.roc.margin_scale) with the config's margin test.

    nice -n 19 .venv/bin/python bench/heldout_scorers.py [--frames 40] [--train-frames 20] [--band2 15]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from report import add_model_arguments, shown_path, write_json

from tofd.algorithm.detector import Candidates, Margin, learn_box, load_model
from tofd.config import load_config
from tofd.drivers.emulator.render import FACE_NAMES
from tofd.lab.ellipsoid import learn_ellipsoid
from tofd.lab.evaluation import NOSE_RADIUS_M, PixelTable, extract_samples, has_nose, shape_box, subject_groups
from tofd.lab.faces import HOLDOUT_SUBJECTS, SHAPE_TRAIN_SUBJECTS, SUBJECTS, render_frames
from tofd.lab.roc import answers_at, margin_scale, roc_from_min_distances

TRAIN_DISTANCES_M = (0.45, 0.50, 0.55, 0.60, 0.65, 0.70)
POSITIVE_RADIUS_M = 0.005
SCORERS = {  # name -> (kind, columns: (band, variant) tables whose features are stacked)
    "box": ("box", (("band1", "nfft_range"),)),
    "box_2band": ("box", (("band1", "nfft_range"), ("band2", "nfft_range"))),
    "ellipsoid": ("ellipsoid", (("band1", "nfft_range"),)),
    "ellipsoid_2band": ("ellipsoid", (("band1", "nfft_range"), ("band2", "nfft_range"))),
    "ellipsoid_2band_amp": ("ellipsoid", (("band1", "nfft_range_amp"), ("band2", "nfft_range"))),
}


@dataclasses.dataclass
class Pixels:
    """Candidate pixels of a set of frames, each band's features side by side."""

    table: PixelTable  # band 1's table: frames, labels (true nose: within NOSE_RADIUS_M), points
    positive: np.ndarray  # (P,) within POSITIVE_RADIUS_M of the tip
    features: dict[str, np.ndarray]  # scorer -> (P, k)
    has_nose: np.ndarray  # (F,)


def pixels(samples: dict[str, list], candidates: Candidates) -> Pixels:
    tables = {(band, variant): PixelTable(samples[band], variant, NOSE_RADIUS_M, candidates)
              for _, columns in SCORERS.values() for band, variant in columns}
    first = tables["band1", "nfft_range"]
    if any(not np.array_equal(t.frame, first.frame) for t in tables.values()):
        raise SystemExit("heldout_scorers: the bands' candidate pixels differ")
    positive = PixelTable(samples["band1"], "nfft_range", POSITIVE_RADIUS_M, candidates).true
    features = {name: np.hstack([tables[c].features for c in columns]) for name, (_, columns) in SCORERS.items()}
    return Pixels(first, positive, features, has_nose(samples["band1"], NOSE_RADIUS_M))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=40, help="test frames per identity")
    parser.add_argument("--train-frames", type=int, default=20, help="training frames per identity")
    parser.add_argument("--distance", type=float, default=0.70, help="test distance of the nose tip, metres")
    parser.add_argument("--band2", type=float, default=15.0, help="second band's tuning frequency, per metre")
    parser.add_argument("--train-mesh", default="both", choices=("both", *FACE_NAMES),
                        help="train on this base mesh's identities only, test on the other's (a head never seen)")
    parser.add_argument("--seed", type=int, default=46)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="JSON (default bench/results/heldout_scorers_<train-mesh>.json)")
    args = parser.parse_args()
    start = time.monotonic()
    cfg = load_config(args.config)
    shipped = load_model(args.model)
    candidates = Candidates.from_config(cfg.detector, cfg.segmentation)
    margin = Margin.from_config(cfg.detector)
    f1 = cfg.features
    f2 = dataclasses.replace(f1, tuning_frequency_per_m=args.band2,
                             lowpass_sigma_per_m=f1.lowpass_sigma_per_m * args.band2 / f1.tuning_frequency_per_m)
    train_subjects = tuple(s for s in dict.fromkeys((*shipped.training.get("subjects", ()), *SHAPE_TRAIN_SUBJECTS))
                           if args.train_mesh in ("both", SUBJECTS[s].mesh))
    test_subjects = tuple(s for s in HOLDOUT_SUBJECTS if SUBJECTS[s].mesh != args.train_mesh)
    if set(train_subjects) & set(HOLDOUT_SUBJECTS):
        raise SystemExit(f"heldout_scorers: a held-out identity among the training ones ({', '.join(train_subjects)})")

    def render(subjects: tuple[str, ...], distances: tuple[float, ...], frames: int, seed: int) -> tuple:
        ds = render_frames(subjects, distances, frames, seed)
        bands = {b: extract_samples(ds, f, cfg.segmentation, args.workers) for b, f in (("band1", f1), ("band2", f2))}
        print(f"rendered {len(ds)} frames ({time.monotonic() - start:.0f} s)")
        return ds, pixels(bands, candidates)

    _, train = render(train_subjects, TRAIN_DISTANCES_M, args.train_frames * len(train_subjects), args.seed)
    test_ds, test = render(test_subjects, (args.distance,), args.frames * len(test_subjects), args.seed + 1)
    groups = subject_groups(test_ds.subject)
    rows, summary = [], {}
    for name, (kind, _) in SCORERS.items():
        x = train.features[name]
        if kind == "box":
            features = tuple(f"f{i}" for i in range(x.shape[1]))
            scorer, _ = shape_box(learn_box(x[train.positive], features, shipped.quantile), _with(train.table, x),
                                  train.has_nose)
        else:
            scorer = learn_ellipsoid(x[train.positive])
        t_true, t_false = train.table.min_distances(scorer.distance(x))
        train_roc = roc_from_min_distances(t_true, t_false, train.has_nose)
        scale = margin_scale(t_true, t_false, train.has_nose, train_roc.eer_scale)
        summary[name] = {"features": x.shape[1], "train_eer": round(train_roc.eer, 4), "operating_scale": scale}
        d = scorer.distance(test.features[name])
        true_min, false_min = test.table.min_distances(d)
        rival = test.table.rivals(d)
        for key, sel in (("all", np.arange(len(test_ds))), *groups.items()):
            roc = roc_from_min_distances(true_min[sel], false_min[sel], test.has_nose[sel])
            a = answers_at(true_min[sel], false_min[sel], scale, rival[sel], margin)
            rows.append({"scorer": name, "identity": key, "frames": int(len(sel)), "eer": round(roc.eer, 4),
                         "found": round(a.found, 4), "wrong": round(a.wrong, 4)})
    keys = ("all", *groups)
    print(f"\nNFFT scorers on held-out identities at {args.distance:.2f} m: EER % | found/wrong %")
    print(f"{'scorer':<22}{'train EER':>10}" + "".join(f"{k:>16}" for k in keys))
    cell = {(r["scorer"], r["identity"]): r for r in rows}
    for name in SCORERS:
        cells = "".join(f"{100 * c['eer']:.1f} | {100 * c['found']:.0f}/{100 * c['wrong']:.0f}".rjust(16)
                        for c in (cell[name, k] for k in keys))
        print(f"{name:<22}{100 * summary[name]['train_eer']:>10.1f}{cells}")
    out = args.out or Path(__file__).parent / "results" / f"heldout_scorers_{args.train_mesh}.json"
    write_json(out, {"title": f"NFFT scorers beyond one box on identities never seen, trained on {args.train_mesh} "
                            "(bench/heldout_scorers.py)",
                          "about": __doc__.split("\n\n")[1].replace("\n", " "), "distance_m": args.distance,
                          "band1_per_m": f1.tuning_frequency_per_m, "band2_per_m": args.band2,
                          "frames_per_identity": args.frames, "train_frames_per_identity": args.train_frames,
                          "train_distances_m": list(TRAIN_DISTANCES_M), "train_subjects": list(train_subjects),
                          "train_mesh": args.train_mesh, "test_subjects": list(test_subjects),
                          "model": shown_path(args.model),
                          "seed": args.seed, "scorers": [{"scorer": k, **v} for k, v in summary.items()],
                          "rows": rows, "elapsed_s": round(time.monotonic() - start, 1)})


def _with(table: PixelTable, features: np.ndarray) -> PixelTable:
    """The table with other feature columns for the same pixels (shape_box reads table.features)."""
    out = PixelTable.__new__(PixelTable)
    out.n_frames, out.frame, out.true, out.xyz = table.n_frames, table.frame, table.true, table.xyz
    out.features = features
    return out


if __name__ == "__main__":
    main()
