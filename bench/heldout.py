"""The box detector on identities it has never seen: static poses at one distance, per identity, per variant.

Test frames: each identity of tofd.lab.faces.HOLDOUT_SUBJECTS (heads of the ICT model and drawn face shapes,
never trained or tuned on) and,
as a second table, OLD_HOLDOUT_SUBJECTS (the earlier held-out pair: scaled copies of the training meshes),
rendered at --distance (SR3000 geometry, yaw +-30, pitch +-15 deg; the training sensor, or --condition). Models
(all four of the paper's variants each, the box of Haker et al.; candidates and margin test from the config):
- shipped: config/nose_model.json (or --model);
- box_shapes: the box trained as the shipped one is (tofd.lab.evaluation.train_model, 0.60 m, training sensor),
  on the shipped model's subjects plus SHAPE_TRAIN_SUBJECTS;
- box_shapes_far: the same identities at 0.45-0.70 m.
Per model, variant and identity: the per-image ROC's EER and what the pipeline reports (nose found / wrong).

    nice -n 19 .venv/bin/python bench/heldout.py [--frames 40] [--train-frames 20] [--distance 0.70] [--condition C]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from report import add_model_arguments, model_setup, shown_path, write_json

from tofd.lab.conditions import CONDITIONS, TRAIN_CONDITION
from tofd.lab.evaluation import evaluate_model, extract_samples, train_model
from tofd.lab.faces import (
    HOLDOUT_SUBJECTS,
    OLD_HOLDOUT_SUBJECTS,
    SHAPE_TRAIN_SUBJECTS,
    TRAIN_DISTANCES_M,
    render_frames,
)
from tofd.lab.report import LABELS

FAR_DISTANCES_M = (0.45, 0.50, 0.55, 0.60, 0.65, 0.70)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=40, help="test frames per identity")
    parser.add_argument("--train-frames", type=int, default=20, help="training frames per identity (retrained boxes)")
    parser.add_argument("--distance", type=float, default=0.70, help="test distance of the nose tip, metres")
    parser.add_argument("--condition", default=TRAIN_CONDITION, choices=tuple(CONDITIONS),
                        help="sensor condition of the test frames (tofd.lab.conditions; training: the training sensor)")
    parser.add_argument("--seed", type=int, default=46)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default=None, help="JSON (default bench/results/heldout.json; with another "
                                                    "--condition heldout_<condition>.json)")
    args = parser.parse_args()
    start = time.monotonic()
    cfg, candidates, margin, shipped = model_setup(args)
    train_subjects = tuple(dict.fromkeys((*shipped.training.get("subjects", ()), *SHAPE_TRAIN_SUBJECTS)))
    if set(train_subjects) & {*HOLDOUT_SUBJECTS, *OLD_HOLDOUT_SUBJECTS}:
        raise SystemExit(f"heldout: {args.model} was trained on a held-out identity ({', '.join(train_subjects)})")

    def samples(subjects: tuple[str, ...], distances: tuple[float, ...], frames: int, seed: int,
                condition: str = TRAIN_CONDITION) -> tuple:
        ds = render_frames(subjects, distances, frames, seed, model=CONDITIONS[condition])
        return ds, extract_samples(ds, cfg.features, cfg.segmentation, args.workers)

    models = {"shipped": shipped}
    for name, distances in (("box_shapes", TRAIN_DISTANCES_M), ("box_shapes_far", FAR_DISTANCES_M)):
        _, train = samples(train_subjects, distances, args.train_frames * len(train_subjects), args.seed)
        models[name] = train_model(train, cfg.features, cfg.segmentation, shipped.quantile,
                                   shipped.positive_radius_mm / 1e3, candidates=candidates,
                                   training={"subjects": list(train_subjects), "distances_m": list(distances)})
        print(f"trained {name} on {len(train)} frames ({time.monotonic() - start:.0f} s)")
    out: dict = {"title": f"Box detector on identities it has never seen, static poses, {args.condition} "
                          "(bench/heldout.py)", "condition": args.condition,
                 "about": __doc__.split("\n\n")[1].replace("\n", " "), "distance_m": args.distance,
                 "frames_per_identity": args.frames, "train_frames_per_identity": args.train_frames, "seed": args.seed,
                 "model": shown_path(args.model), "train_subjects": list(train_subjects),
                 "heldout_subjects": list(HOLDOUT_SUBJECTS), "old_heldout_subjects": list(OLD_HOLDOUT_SUBJECTS)}
    for table, subjects in (("heldout", HOLDOUT_SUBJECTS), ("old_heldout", OLD_HOLDOUT_SUBJECTS)):
        ds, test = samples(subjects, (args.distance,), args.frames * len(subjects), args.seed + 1, args.condition)
        rows = []
        for name, model in models.items():
            results = evaluate_model(model, test, ds.distance_m, candidates=candidates, margin=margin,
                                     subject=ds.subject)
            for variant, r in results.items():
                cells = [("all", r.overall, r.answers),
                         *((s, r.per_subject[s], r.answers_per_subject[s]) for s in subjects)]
                rows += [{"model": name, "variant": variant, "identity": key, "frames": roc.n_images,
                          "eer": round(roc.eer, 4), "found": round(a.found, 4), "wrong": round(a.wrong, 4)}
                         for key, roc, a in cells]
        out[f"{table}_rows"] = rows
        print_table(table, subjects, rows)
    out["models"] = {name: {"training": m.training, "operating_scale": {v: vm.operating_scale
                                                                         for v, vm in m.variants.items()}}
                     for name, m in models.items()}
    out["elapsed_s"] = round(time.monotonic() - start, 1)
    suffix = "" if args.condition == TRAIN_CONDITION else f"_{args.condition}"
    write_json(args.out or Path(__file__).parent / "results" / f"heldout{suffix}.json", out)


def print_table(table: str, subjects: tuple[str, ...], rows: list[dict]) -> None:
    """Rows: model x variant; columns: EER % | found/wrong % overall and per identity."""
    head = f"{'model':<16}{'variant':<16}{'all':>16}" + "".join(f"{s:>16}" for s in subjects)
    print(f"\n{table}: EER % | found/wrong %")
    print(head)
    print("-" * len(head))
    cell = {(r["model"], r["variant"], r["identity"]): r for r in rows}
    for model, variant in dict.fromkeys((r["model"], r["variant"]) for r in rows):
        text = [f"{100 * c['eer']:.1f} | {100 * c['found']:.0f}/{100 * c['wrong']:.0f}"
                for c in (cell[model, variant, key] for key in ("all", *subjects))]
        print(f"{model:<16}{LABELS.get(variant, variant):<16}" + "".join(f"{t:>16}" for t in text), flush=True)


if __name__ == "__main__":
    main()
