"""Choose the nose track's report_coast_s on the TRAINING subjects' head-motion sequences (never the held-out ones).

Each sequence (tofd.lab.sequences: 0.35-0.70 m sweep with yaw and pitch, 20 fps) of each subject in
tofd.lab.faces.CV_SUBJECTS is rendered and detected once per sensor condition; the track is then run over the
same detections for every value of report_coast_s (seconds a confirmed track keeps reporting its nose after its
last associated detection). Prints, per value, the mean found / wrong % of the tracked answers per condition and
writes JSON (bench/results/tune_tracker.json by default).

    .venv/bin/python bench/tune_tracker.py [--frames 240] [--conditions train_sensor,noise_x2,dark_face]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from report import add_sequence_arguments, sequence_detector, shown_path, write_json

from tofd.algorithm.tracking import TrackerConfig
from tofd.lab.conditions import CONDITIONS
from tofd.lab.faces import CV_SUBJECTS
from tofd.lab.sequences import detect_sequence, score_sequence

COAST_S = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_sequence_arguments(parser)
    parser.add_argument("--seed", type=int, default=500)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "tune_tracker.json"))
    args = parser.parse_args()
    start = time.monotonic()
    conditions, _, detector = sequence_detector(args, "tune_tracker")
    sequences = {name: [detect_sequence(detector, subject, args.frames, seed=args.seed + 10 * si + ci,
                                        model=CONDITIONS[name]) for si, subject in enumerate(CV_SUBJECTS)]
                 for ci, name in enumerate(conditions)}
    rows = []
    print(f"{'coast s':>8}  " + "  ".join(f"{name + ' found / wrong %':>30}" for name in conditions))
    for coast in COAST_S:
        row: dict = {"report_coast_s": coast}
        for name, seqs in sequences.items():
            scored = [score_sequence(s, tracker=TrackerConfig(report_coast_s=coast)) for s in seqs]
            row[name] = {"track_found": float(np.mean([r.track_found for r in scored])),
                         "track_wrong": float(np.mean([r.track_wrong for r in scored])),
                         "worst_track_wrong": float(max(r.track_wrong for r in scored))}
        rows.append(row)
        cells = (f"{100 * row[n]['track_found']:>21.1f} / {100 * row[n]['track_wrong']:<6.2f}" for n in conditions)
        print(f"{coast:8.2f}  " + "  ".join(cells), flush=True)
    write_json(args.out, {"title": "Nose track report_coast_s on the training subjects (bench/tune_tracker.py)",
                          "about": "Mean over the CV subjects' head-motion sequences of the tracked answers' found / "
                                   "wrong shares, per sensor condition, for each report_coast_s.",
                          "model": shown_path(args.model), "subjects": list(CV_SUBJECTS), "frames": args.frames,
                          "default_report_coast_s": TrackerConfig().report_coast_s, "rows": rows,
                          "seconds": round(time.monotonic() - start, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
