"""Issue 34/33's evaluation: the per-frame answer and the nose track per 0.05 m bin on held-out identities in motion.

Rendered head-motion sequences (tofd.lab.sequences, ISSUE_MOTION: 0.35 -> 0.70 -> 0.35 m over the sequence, yaw
+-25, pitch +-10 deg, drifting) of identities never trained or tuned on (tofd.lab.faces.HOLDOUT_SUBJECTS), in any
camera geometry (--camera: tofd.lab.cameras), with the shipped model and the configured detector; per bin the
shares of frames whose answer is within 5 px / beyond 10 px of the true tip (and within 10 mm / beyond 20 mm in
3-D), per frame and with the track, pooled over subjects, per sensor condition.

    .venv/bin/python bench/sequences.py [--camera sr3000|k4a-nfov|W,H,fx,fy,cx,cy] [--frames 450] [--fps 30]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from report import add_model_arguments, shown_path, write_json

from tofd.lab.cameras import INTRINSICS_HELP, parse_intrinsics
from tofd.lab.conditions import CONDITIONS, parse_conditions
from tofd.lab.faces import HOLDOUT_SUBJECTS, parse_subjects
from tofd.lab.sequences import ISSUE_MOTION, BinScore, detect_sequence, score_bins

SHARES = tuple(f.name for f in dataclasses.fields(BinScore) if f.name not in ("distance_m", "frames")
               and not f.name.endswith("_mm"))
PIXEL_GOALS = {"det_within_5px": (">=", 0.90), "det_beyond_10px": ("<=", 0.01), "track_within_5px": (">=", 0.97),
               "track_beyond_10px": ("<=", 0.01)}
"""Issue 34's goals per bin (pixels, per frame and with the track)."""
METRIC_GOALS = {"track_within_10mm": (">=", 0.97), "track_beyond_20mm": ("<=", 0.01)}
"""Issue 33's goals per bin (3-D distance of the track's nose from the true tip), on every camera."""
HEADS = {"det_within_5px": "det<=5px", "det_beyond_10px": "det>10px", "det_none": "det none",
         "det_within_10mm": "det<=10mm", "det_beyond_20mm": "det>20mm", "track_within_5px": "trk<=5px",
         "track_beyond_10px": "trk>10px", "track_none": "trk none", "track_within_10mm": "trk<=10mm",
         "track_beyond_20mm": "trk>20mm"}


def meets(row: dict, goals: dict) -> bool:
    return all((row[k] >= v) if op == ">=" else (row[k] <= v) for k, (op, v) in goals.items())


def pooled(scores: list[list[BinScore]]) -> list[dict]:
    """Per bin over several sequences: the frame-weighted shares (and the largest median error, mm)."""
    out: dict[float, dict] = {}
    for seq in scores:
        for b in seq:
            row = out.setdefault(b.distance_m, {"distance_m": b.distance_m, "frames": 0,
                                                **{k: 0.0 for k in SHARES}, "det_median_mm": None,
                                                "track_median_mm": None})
            for k in SHARES:
                row[k] += getattr(b, k) * b.frames
            row["frames"] += b.frames
            for k in ("det_median_mm", "track_median_mm"):
                v = getattr(b, k)
                row[k] = v if row[k] is None else max(row[k], v) if v is not None else row[k]
    rows = [out[d] for d in sorted(out)]
    for row in rows:
        for k in SHARES:
            row[k] = round(row[k] / row["frames"], 4)
        row["pixel_goals_met"], row["metric_goals_met"] = meets(row, PIXEL_GOALS), meets(row, METRIC_GOALS)
    return rows


def table(rows: list[dict]) -> str:
    head = "".join(f"{HEADS[k]:>10}" for k in SHARES)
    lines = [f"{'bin m':>6}{'frames':>7}{head}{'trk mm':>8}{'px/mm goals':>12}"]
    for r in rows:
        cells = "".join(f"{100 * r[k]:>9.1f}%" for k in SHARES)
        med = "-" if r["track_median_mm"] is None else f"{r['track_median_mm']:.1f}"
        goals = f"{'yes' if r['pixel_goals_met'] else 'NO'}/{'yes' if r['metric_goals_met'] else 'NO'}"
        lines.append(f"{r['distance_m']:>6.2f}{r['frames']:>7}{cells}{med:>8}{goals:>12}")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--camera", default="sr3000", help=INTRINSICS_HELP)
    parser.add_argument("--frames", type=int, default=450, help="frames per sequence (one 0.35-0.70-0.35 m sweep)")
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--subjects", default=",".join(HOLDOUT_SUBJECTS), help="held-out identities, comma-separated")
    parser.add_argument("--conditions", default="train_sensor", help="sensor conditions (tofd.lab.conditions)")
    parser.add_argument("--seed", type=int, default=34)
    parser.add_argument("--out", default=None, help="JSON (default bench/results/sequences_<camera>.json)")
    args = parser.parse_args()
    from tofd.algorithm.detector import NoseDetector, load_model
    from tofd.config import load_config

    try:
        intrinsics = parse_intrinsics(args.camera)
        conditions = parse_conditions(args.conditions)
        subjects = parse_subjects(args.subjects)
    except ValueError as exc:
        raise SystemExit(f"sequences: {exc}") from None
    cfg = load_config(args.config)
    detector = NoseDetector(load_model(args.model), cfg.detector, cfg.features, cfg.segmentation, intrinsics)
    camera = args.camera if args.camera in ("sr3000", "k4a-nfov") else f"{intrinsics.width}x{intrinsics.height}"
    start = time.monotonic()
    result: dict = {"title": f"Nose tip per distance bin, held-out identities in motion, {camera} (bench/sequences.py)",
                    "about": __doc__.split("\n\n")[1].replace("\n", " "), "camera": camera,
                    "intrinsics": intrinsics.to_dict(), "model": shown_path(args.model),
                    "variant": cfg.detector.variant, "frames": args.frames, "fps": args.fps,
                    "motion": dataclasses.asdict(ISSUE_MOTION), "subjects": list(subjects), "pixel_goals": PIXEL_GOALS,
                    "metric_goals": METRIC_GOALS,
                    "bins": []}
    for ci, name in enumerate(conditions):
        scores = []
        for si, subject in enumerate(subjects):
            seq = detect_sequence(detector, subject, args.frames, fps=args.fps, sweep_s=args.frames / args.fps,
                                  seed=args.seed + 100 * ci + si, model=CONDITIONS[name], motion=ISSUE_MOTION)
            scores.append(score_bins(seq))
        rows = pooled(scores)
        result["bins"] += [{"condition": name, **row} for row in rows]
        print(f"{camera}, {name}, {', '.join(subjects)} ({args.frames} frames each):\n{table(rows)}", flush=True)
    result["seconds"] = round(time.monotonic() - start, 1)
    write_json(args.out or Path(__file__).parent / "results" / f"sequences_{camera}.json", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
