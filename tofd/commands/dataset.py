"""Labelled face datasets for the nose detector: `tofd dataset generate OUT.npz` renders one.

The file layout is documented in tofd/lab/dataset.py (one .npz, no pickle, plus an intrinsics JSON sidecar).
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    gen = sub.add_parser("generate", help="render a labelled train or test split (tofd/lab/faces.py)")
    gen.add_argument("out", metavar="OUT.npz", help="dataset file to write (and OUT.json, the intrinsics)")
    gen.add_argument("--split", choices=("train", "test"), default="train",
                     help="train: three subjects at 0.60 m; test: a fourth subject at 0.35-0.70 m")
    gen.add_argument("--frames", type=int, default=120, help="number of frames (default 120)")
    gen.add_argument("--seed", type=int, default=0, help="random seed of poses and sensor noise")


def main(args: argparse.Namespace) -> int:
    from tofd.lab.dataset import save_dataset
    from tofd.lab.faces import generate
    from tofd.progress import Progress

    if args.frames < 1:
        print(f"tofd dataset: --frames must be >= 1, got {args.frames}", file=sys.stderr)
        return 2
    progress = Progress(f"rendering {args.split}", args.frames)
    ds = generate(args.split, args.frames, args.seed, progress=progress.update)
    progress.done()
    path = save_dataset(ds, args.out)
    subjects = ", ".join(sorted(set(ds.subject)))
    print(f"wrote {path}: {len(ds)} frames, subjects {subjects}, "
          f"distances {ds.distance_m.min():.2f}-{ds.distance_m.max():.2f} m")
    return 0
