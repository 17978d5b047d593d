"""Leave one mesh out: the box trained on the identities of one base mesh, tested on unseen identities of the other.

The closest stand-in here for a head never seen: every identity is a deformation of one of two scanned meshes
(tofd.lab.faces), so a box trained on one mesh's family meets a different head on the other's. Training (as the
shipped model is trained: tofd.lab.evaluation.train_model, --train-frames per identity at 0.60 m, the training
sensor), one set of rendered frames shared by all models:
- <mesh>_base: the mesh and its hand-made variants of CV_SUBJECTS (lps, lps_flat | mp, mp_broad, mp_chin);
- <mesh>_shapes: those plus the mesh's drawn face shapes of SHAPE_TRAIN_SUBJECTS (more shape diversity);
- both_base, both_shapes: the same on both meshes; shipped: config/nose_model.json (or --model) as it is.
Test: static poses (yaw +-30, pitch +-15 deg, SR3000 geometry) of the identities no model trains on, per mesh:
SHAPE_TUNE_SUBJECTS, HOLDOUT_SUBJECTS and OLD_HOLDOUT_SUBJECTS, at each --distances under each --conditions.
Per model, test mesh, distance and condition: the per-image ROC's EER and what the pipeline reports (nose found /
wrong; candidates and margin test from the config), for the paper's FFT and NFFT range variants, and per identity
for NFFT range. A model's `trained_on` names its meshes; cross-mesh cells are those whose test mesh is not one.

    nice -n 10 .venv/bin/python bench/cross_mesh.py [--frames 120] [--train-frames 40] [--distances 0.60,0.70]
                                                    [--seed 46]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from report import add_model_arguments, model_setup, shown_path, write_json

from tofd.algorithm.detector import NoseModel
from tofd.drivers.emulator.render import FACE_NAMES
from tofd.lab.conditions import CONDITIONS, parse_conditions
from tofd.lab.evaluation import evaluate_model, extract_samples, train_model
from tofd.lab.faces import (
    CV_SUBJECTS,
    HOLDOUT_SUBJECTS,
    OLD_HOLDOUT_SUBJECTS,
    SHAPE_TRAIN_SUBJECTS,
    SHAPE_TUNE_SUBJECTS,
    SUBJECTS,
    TRAIN_DISTANCES_M,
    render_frames,
)

SHORT = {"lee_perry_smith": "lps", "mediapipe_canonical": "mp"}
TABLE_VARIANTS = ("nfft_range", "fft_range")  # the paper's range-only comparison
IDENTITY_VARIANT = "nfft_range"
SEED = 46


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=120, help="test frames per identity, distance and condition")
    parser.add_argument("--train-frames", type=int, default=40, help="training frames per identity")
    parser.add_argument("--distances", default="0.60,0.70", help="comma-separated test distances of the nose, m")
    parser.add_argument("--conditions", default="train_sensor,noise_x2",
                        help="comma-separated sensor conditions of the test frames (tofd.lab.conditions)")
    parser.add_argument("--seed", type=int, default=SEED, help="seed of the training frames (test: seed + 1, + 2...)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="JSON (default bench/results/cross_mesh.json; with another "
                                                    "--seed cross_mesh_seed<seed>.json)")
    args = parser.parse_args()
    try:
        conditions = parse_conditions(args.conditions)
        distances = tuple(float(d) for d in args.distances.split(","))
    except ValueError as exc:
        raise SystemExit(f"cross_mesh: {exc}") from None
    start = time.monotonic()
    cfg, candidates, margin, shipped = model_setup(args)
    base = CV_SUBJECTS
    arms = {f"{SHORT[m]}_{kind}": subjects_on(subjects, m) for m in FACE_NAMES
            for kind, subjects in (("base", base), ("shapes", (*base, *SHAPE_TRAIN_SUBJECTS)))}
    arms |= {"both_base": base, "both_shapes": (*base, *SHAPE_TRAIN_SUBJECTS)}
    test_subjects = tuple(s for m in FACE_NAMES
                          for s in subjects_on((*SHAPE_TUNE_SUBJECTS, *HOLDOUT_SUBJECTS, *OLD_HOLDOUT_SUBJECTS), m))
    seen = sorted(set(test_subjects) & {*base, *SHAPE_TRAIN_SUBJECTS})
    if seen:
        raise SystemExit(f"cross_mesh: a test identity is trained on ({', '.join(seen)})")

    def elapsed() -> str:
        return f"{time.monotonic() - start:.0f} s"

    train_names = tuple(dict.fromkeys(s for subjects in arms.values() for s in subjects))
    train_ds = render_frames(train_names, TRAIN_DISTANCES_M, args.train_frames * len(train_names), args.seed)
    train_samples = extract_samples(train_ds, cfg.features, cfg.segmentation, args.workers)
    models: dict[str, NoseModel] = {"shipped": shipped}
    for name, subjects in arms.items():
        chosen = [s for s, who in zip(train_samples, train_ds.subject, strict=True) if who in subjects]
        models[name] = train_model(chosen, cfg.features, cfg.segmentation, shipped.quantile,
                                   shipped.positive_radius_mm / 1e3, candidates=candidates,
                                   training={"subjects": list(subjects), "distances_m": list(TRAIN_DISTANCES_M)})
        print(f"trained {name} on {len(chosen)} frames of {', '.join(subjects)} ({elapsed()})", flush=True)
    trained_on = {name: sorted({SHORT[SUBJECTS[s].mesh] for s in m.training.get("subjects", ())})
                  for name, m in models.items()}
    rows: list[dict] = []
    identity_rows: list[dict] = []
    for k, condition in enumerate(conditions):
        ds = render_frames(test_subjects, distances, args.frames * len(test_subjects) * len(distances),
                           args.seed + 1 + k, model=CONDITIONS[condition])
        test = extract_samples(ds, cfg.features, cfg.segmentation, args.workers)
        print(f"rendered {len(ds)} test frames, {condition} ({elapsed()})", flush=True)
        where = np.array([f"{d:.2f}" for d in ds.distance_m])
        cells = {"identity": np.char.add(np.char.add(where, "|"), ds.subject.astype(str)),
                 "mesh": np.char.add(np.char.add(where, "|"), [SHORT[SUBJECTS[s].mesh] for s in ds.subject])}
        for name, model in models.items():
            for group, labels in cells.items():
                results = evaluate_model(model, test, ds.distance_m, candidates=candidates, margin=margin,
                                         subject=labels)
                for variant in TABLE_VARIANTS if group == "mesh" else (IDENTITY_VARIANT,):
                    r = results[variant]
                    for label in np.unique(labels):
                        distance, key = label.split("|")
                        roc, a = r.per_subject[label], r.answers_per_subject[label]
                        mesh = key if group == "mesh" else SHORT[SUBJECTS[key].mesh]
                        row = {"condition": condition, "distance_m": float(distance), "model": name,
                               "trained_on": "+".join(trained_on[name]), "variant": variant, "test": key,
                               "cross_mesh": mesh not in trained_on[name], "frames": roc.n_images,
                               "eer": round(roc.eer, 4), "found": round(a.found, 4), "wrong": round(a.wrong, 4)}
                        (rows if group == "mesh" else identity_rows).append(row)
        print_tables(condition, distances, [r for r in rows if r["condition"] == condition],
                     [r for r in identity_rows if r["condition"] == condition])
    seeded = "" if args.seed == SEED else f"_seed{args.seed}"
    write_json(args.out or Path(__file__).parent / "results" / f"cross_mesh{seeded}.json", {
        "title": "Leave one mesh out: the box on a head never seen in training (bench/cross_mesh.py"
                 f"{'' if args.seed == SEED else f' --seed {args.seed}'})",
        "about": __doc__.split("\n\n")[1].replace("\n", " "), "distances_m": list(distances),
        "conditions": list(conditions), "frames_per_identity": args.frames,
        "train_frames_per_identity": args.train_frames, "seed": args.seed, "model": shown_path(args.model),
        "test_subjects": list(test_subjects),
        "models": [{"model": n, "trained_on": "+".join(trained_on[n]), "frames": m.training.get("frames"),
                    "subjects": " ".join(m.training.get("subjects", ())),
                    "nfft_range_scale": m.variants["nfft_range"].operating_scale} for n, m in models.items()],
        "rows": rows, "identity_rows": identity_rows, "elapsed_s": round(time.monotonic() - start, 1)})


def subjects_on(subjects: tuple[str, ...], mesh: str) -> tuple[str, ...]:
    """The subjects whose base mesh is `mesh`, in order, once each."""
    return tuple(s for s in dict.fromkeys(subjects) if SUBJECTS[s].mesh == mesh)


def print_tables(condition: str, distances: tuple[float, ...], rows: list[dict], identity_rows: list[dict]) -> None:
    """Per distance: models x (variant, test mesh), then models x identity (NFFT range); cells EER % | found/wrong %,
    a cross-mesh cell marked *."""
    def text(r: dict) -> str:
        return f"{'*' if r['cross_mesh'] else ''}{100 * r['eer']:.1f} | {100 * r['found']:.0f}/{100 * r['wrong']:.0f}"

    for distance in distances:
        for title, part, column in (("per test mesh", rows, lambda r: f"{r['variant'].split('_')[0]} {r['test']}"),
                                    ("per identity, NFFT range", identity_rows, lambda r: r["test"])):
            here = [r for r in part if r["distance_m"] == round(distance, 2)]
            columns = list(dict.fromkeys(column(r) for r in here))
            cell = {(r["model"], column(r)): text(r) for r in here}
            print(f"\n{condition}, {distance:.2f} m, {title}: EER % | found/wrong % (* cross-mesh)")
            print(f"{'model':<14}{'trained':>8}" + "".join(f"{c:>16}" for c in columns))
            for model in dict.fromkeys(r["model"] for r in here):
                trained = next(r["trained_on"] for r in here if r["model"] == model)
                print(f"{model:<14}{trained:>8}" + "".join(f"{cell.get((model, c), ''):>16}" for c in columns))


if __name__ == "__main__":
    main()
