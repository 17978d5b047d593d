"""Choose the tip fit's step limit (tofd.algorithm.detector.tip.MAX_STEP_RADII) on the TRAINING subjects' head-motion
sequences (never the held-out ones), on the SR3000 and a 640x576 camera.

Each sequence (tofd.lab.sequences: head motion, 30 fps, 0.35-0.70-0.35 m) of each subject in
tofd.lab.faces.CV_SUBJECTS is rendered and detected once with the shipped model; in every frame at --min-range or
farther whose detection is accepted, the tip is refined from the accepted pixel with each step limit (radii of the
configured tip_radius_m; "inf": the minimum itself, the previous rule). Prints per camera and step the share of
those frames whose tip is farther than 10 mm from the true tip and the median error, and writes JSON
(bench/results/tune_tip.json by default).

    .venv/bin/python bench/tune_tip.py [--frames 450] [--subjects mp_broad,lps] [--cameras sr3000,k4a-nfov]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from report import add_model_arguments, shown_path, write_json

from tofd.algorithm.detector import NoseDetector, load_model
from tofd.algorithm.detector.tip import refine_tip
from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.segmentation import rotation_to_z
from tofd.config import load_config
from tofd.drivers.emulator.render import render_face
from tofd.lab.cameras import parse_intrinsics
from tofd.lab.faces import CV_SUBJECTS, SUBJECTS, make_subject, parse_subjects
from tofd.lab.sequences import ISSUE_MOTION, head_motion

STEPS = (math.inf, 1.0, 0.75, 0.5, 0.35)
FPS = 30.0


def tip_errors(detector: NoseDetector, extractor: FeatureExtractor, subject: str, frames: int, seed: int,
               min_range_m: float) -> np.ndarray:
    """(frames kept, len(STEPS)) distance (m) of each step limit's tip from the true tip (training sensor)."""
    intrinsics = detector.intrinsics
    mesh, rng = make_subject(SUBJECTS[subject]), np.random.default_rng(seed)
    out = []
    for pose in head_motion(np.arange(frames) / FPS, frames / FPS, intrinsics, ISSUE_MOTION):
        r = render_face(mesh, pose, intrinsics, rng)  # every frame, so the noise follows the seed
        truth = np.asarray(r.nose_xyz_m)
        if np.linalg.norm(truth) < min_range_m:
            continue
        ff = extractor(r.range_m, r.amplitude)
        det = detector.detect_maps(ff.maps, r.range_m, ff.rotation[2])
        if not det.accepted or det.nose_px is None:
            continue
        foreground = np.isfinite(ff.maps[detector.box.features[0]])
        rotation = rotation_to_z(np.asarray(ff.rotation[2], dtype=np.float64))
        out.append([np.linalg.norm(np.asarray(refine_tip(r.range_m, foreground, intrinsics, det.nose_px, rotation,
                                                         detector.tip_radius_m, max_step_radii=s).xyz_m) - truth)
                    for s in STEPS])
    return np.asarray(out).reshape(-1, len(STEPS))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=450, help="frames per sequence (one 0.35-0.70-0.35 m sweep)")
    parser.add_argument("--subjects", default="mp_broad,lps", help="training identities (of CV_SUBJECTS)")
    parser.add_argument("--cameras", default="sr3000,k4a-nfov", help="tofd.lab.cameras names or six numbers")
    parser.add_argument("--min-range", type=float, default=0.5, help="metres: frames whose true tip is nearer are "
                                                                     "left out")
    parser.add_argument("--seed", type=int, default=602)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "tune_tip.json"))
    args = parser.parse_args()
    try:
        subjects = parse_subjects(args.subjects)
        if not set(subjects) <= set(CV_SUBJECTS):
            raise ValueError(f"--subjects: only training identities ({', '.join(CV_SUBJECTS)})")
        cameras = {name: parse_intrinsics(name) for name in args.cameras.split(",")}
    except ValueError as exc:
        raise SystemExit(f"tune_tip: {exc}") from None
    cfg = load_config(args.config)
    start = time.monotonic()
    rows = []
    print(f"{'camera':>10} {'step radii':>10} {'frames':>7} {'tip >10 mm':>11} {'median mm':>10}")
    for camera, intrinsics in cameras.items():
        detector = NoseDetector(load_model(args.model), cfg.detector, cfg.features, cfg.segmentation, intrinsics)
        extractor = FeatureExtractor(intrinsics, cfg.features, cfg.segmentation, detector.families)
        errors = np.concatenate([tip_errors(detector, extractor, s, args.frames, args.seed + i, args.min_range)
                                 for i, s in enumerate(subjects)])
        for j, step in enumerate(STEPS):
            e = errors[:, j]
            row = {"camera": camera, "max_step_radii": None if math.isinf(step) else step, "frames": len(e),
                   "tip_beyond_10mm": round(float(np.mean(e > 0.010)), 4),
                   "tip_median_mm": round(1e3 * float(np.median(e)), 2)}
            rows.append(row)
            print(f"{camera:>10} {step:>10g} {len(e):>7} {100 * row['tip_beyond_10mm']:>10.1f}% "
                  f"{row['tip_median_mm']:>10.2f}", flush=True)
    write_json(args.out, {"title": "Tip fit step limit on the training subjects (bench/tune_tip.py)",
                          "about": __doc__.split("\n\n")[1].replace("\n", " "), "model": shown_path(args.model),
                          "tip_radius_m": cfg.detector.tip_radius_m, "subjects": list(subjects),
                          "frames": args.frames, "min_range_m": args.min_range,
                          "seconds": round(time.monotonic() - start, 1), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
