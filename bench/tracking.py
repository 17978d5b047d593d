"""The nose track beside the per-frame detection: rendered head-motion sequences and a replay's results file.

Sequences (tofd.lab.sequences): each held-out identity under a few sensor conditions (tofd.lab.conditions), the
shipped model with the configured detector; found / wrong per frame with and without the track. With
--replay-results DIR/x.results.jsonl (from `tofd replay`), that file's detections and the pipeline's track reported
beside them are scored against its ground-truth pixels (within --replay-px).

    .venv/bin/python bench/tracking.py [--frames 240] [--conditions train_sensor,noise_x2,dark_face]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from report import add_sequence_arguments, sequence_detector, shown_path, write_json

from tofd.lab.accuracy import accuracy_from_results
from tofd.lab.conditions import CONDITIONS
from tofd.lab.faces import HOLDOUT_SUBJECTS
from tofd.lab.sequences import evaluate_sequence


def replay_track(path: Path, max_px: float) -> dict:
    """Per-frame vs tracked answers of a replay's results.jsonl (the pipeline's own track, as reported there): found
    iff within max_px of the ground-truth pixel, wrong iff reported and not found."""
    acc = accuracy_from_results(path, max_px)
    if acc is None or acc.track_error_px is None:
        raise SystemExit(f"tracking: {path}: no ground truth or no track in the results (replay with a model)")
    return {"frames": len(acc.error_px), "detection_found": acc.found, "detection_wrong": acc.wrong,
            "track_found": acc.track_found, "track_wrong": acc.track_wrong}


ABOUT = ("Rendered head-motion sequences (0.35-0.70 m sweep, yaw +-30, pitch +-10 deg, 20 fps) of the held-out "
         "identities; found/wrong per frame without and with the track; replay: the bundled clip's results (within "
         "5 px of ground truth).")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(parser)
    parser.add_argument("--replay-results", default=None, metavar="JSONL")
    parser.add_argument("--replay-px", type=float, default=5.0)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "tracking.json"))
    args = parser.parse_args()
    start = time.monotonic()
    conditions, cfg, detector = sequence_detector(args, "tracking")
    rows = []
    print(f"{'condition':<16}{'subject':<16}{'found / wrong %: per frame':>28}{'tracked':>16}{'reacq.':>8}")
    for ci, name in enumerate(conditions):
        for si, subject in enumerate(HOLDOUT_SUBJECTS):
            r = evaluate_sequence(detector, subject, args.frames, seed=100 * ci + si, model=CONDITIONS[name])
            rows.append({"condition": name, **dataclasses.asdict(r)})
            print(f"{name:<16}{subject:<16}{100 * r.detection_found:>19.1f} / {100 * r.detection_wrong:<6.1f}"
                  f"{100 * r.track_found:>9.1f} / {100 * r.track_wrong:<6.1f}{r.reacquisitions:>6}", flush=True)
    result: dict = {"title": "Nose track vs per-frame detection (bench/tracking.py)", "about": ABOUT,
                    "model": shown_path(args.model), "variant": cfg.detector.variant, "frames": args.frames,
                    "sequences": rows}
    if args.replay_results:
        result["replay"] = replay_track(Path(args.replay_results), args.replay_px)
        print(f"replay {args.replay_results}: {result['replay']}")
    result["seconds"] = round(time.monotonic() - start, 1)
    write_json(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
