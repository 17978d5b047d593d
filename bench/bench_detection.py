"""Segmentation and detection time per frame at each camera geometry, as ratios to the SR3000's in the same run.

Frames of a held-out identity rendered at 0.35-0.70 m (yaw 15, pitch 5 deg) per camera; the detector's features
(its variant's family) computed once per frame outside the timing; then segmentation (tofd.algorithm.segmentation
.segment_face) and detection (NoseDetector.detect_maps, candidate tests and tip fit included) timed per call,
cameras interleaved round by round so that load on the machine hits them alike; medians over calls.

    .venv/bin/python bench/bench_detection.py [--cameras sr3000,k4a-nfov] [--rounds 7]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from report import add_model_arguments, shown_path, write_json

from tofd.lab.cameras import parse_intrinsics

DISTANCES_M = (0.35, 0.45, 0.55, 0.70)
GOAL_RATIO = 4.0  # per-frame stage time at 640x576 at most this times the SR3000's


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_model_arguments(parser)
    parser.add_argument("--cameras", default="sr3000,k4a-nfov", help="comma-separated; the first is the baseline")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--out", default=str(Path(__file__).parent / "results" / "bench_detection.json"))
    args = parser.parse_args()
    from tofd.algorithm.detector import NoseDetector, load_model
    from tofd.algorithm.extract import FeatureExtractor
    from tofd.algorithm.names import families_for
    from tofd.algorithm.segmentation import segment_face
    from tofd.config import load_config
    from tofd.drivers.emulator.render import Pose, render_face
    from tofd.lab.faces import HOLDOUT_SUBJECTS, SUBJECTS, make_subject

    cfg, model = load_config(args.config), load_model(args.model)
    mesh = make_subject(SUBJECTS[HOLDOUT_SUBJECTS[0]])
    cameras = [c.strip() for c in args.cameras.split(",") if c.strip()]
    setups = {}
    for name in cameras:
        intr = parse_intrinsics(name)
        rng = np.random.default_rng(0)
        frames = [render_face(mesh, Pose(d, 15.0, 5.0), intr, rng) for d in DISTANCES_M]
        detector = NoseDetector(model, cfg.detector, cfg.features, cfg.segmentation, intr)
        extractor = FeatureExtractor(intr, cfg.features, cfg.segmentation, families_for(detector.box.features))
        setups[name] = (intr, frames, detector, [extractor(f.range_m, f.amplitude) for f in frames])
    times: dict[str, dict[str, list[float]]] = {n: {"segmentation": [], "detection": []} for n in cameras}
    for _ in range(args.rounds):
        for name, (intr, frames, detector, ffs) in setups.items():
            for f, ff in zip(frames, ffs, strict=True):
                t0 = time.perf_counter()
                segment_face(f.range_m, f.amplitude, cfg.segmentation, intr)
                t1 = time.perf_counter()
                detector.detect_maps(ff.maps, f.range_m, ff.rotation[2])
                t2 = time.perf_counter()
                times[name]["segmentation"].append((t1 - t0) * 1e3)
                times[name]["detection"].append((t2 - t1) * 1e3)
    base = cameras[0]
    rows = []
    print(f"{'camera':<12}{'pixels':>9}{'segm. ms':>10}{'ratio':>7}{'detect ms':>11}{'ratio':>7}")
    for name in cameras:
        intr = setups[name][0]
        row = {"camera": name, "width": intr.width, "height": intr.height, "pixels": intr.width * intr.height}
        for stage in ("segmentation", "detection"):
            row[f"{stage}_ms"] = round(float(np.median(times[name][stage])), 3)
            row[f"{stage}_ratio"] = round(row[f"{stage}_ms"] / float(np.median(times[base][stage])), 2)
        rows.append(row)
        print(f"{name:<12}{row['pixels']:>9}{row['segmentation_ms']:>10.2f}{row['segmentation_ratio']:>7.2f}"
              f"{row['detection_ms']:>11.2f}{row['detection_ratio']:>7.2f}")
    write_json(args.out, {"title": "Segmentation and detection per frame by camera (bench/bench_detection.py)",
                          "about": __doc__.split("\n\n")[1].replace("\n", " "), "baseline": base,
                          "goal_ratio": GOAL_RATIO, "model": shown_path(args.model), "rounds": args.rounds,
                          "distances_m": list(DISTANCES_M), "cameras": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
