"""Labelled face datasets for the nose detector: `tofd dataset generate OUT.npz` renders one.

One .npz (no pickle) with keys range, amplitude (F x H x W of the camera, by default the SR3000's 144 x 176),
nose_px, nose_visible, distance_m, yaw_deg, pitch_deg, subject, nose_xyz_m, plus OUT.json holding the intrinsics
(--intrinsics: any camera geometry).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tofd.lab.cameras import INTRINSICS_HELP

    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    gen = sub.add_parser("generate", help="render a labelled train or test split of synthetic faces")
    gen.add_argument("out", metavar="OUT.npz", help="dataset file to write (and OUT.json, the intrinsics)")
    gen.add_argument("--split", choices=("train", "test"), default="train",
                     help="train: three subjects at 0.60 m; test: a fourth subject at 0.35-0.70 m")
    gen.add_argument("--frames", type=int, default=120, help="number of frames (default 120)")
    gen.add_argument("--seed", type=int, default=0, help="random seed of poses and sensor noise")
    gen.add_argument("--intrinsics", default="sr3000", metavar="CAMERA", help=INTRINSICS_HELP)


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.lab.cameras import parse_intrinsics
    from tofd.lab.dataset import save_dataset
    from tofd.lab.faces import generate
    from tofd.outputs import check_output_file
    from tofd.progress import Progress

    if args.frames < 1:
        raise UsageError(f"--frames must be >= 1, got {args.frames}")
    try:
        intrinsics = parse_intrinsics(args.intrinsics)
    except ValueError as exc:
        raise UsageError(f"--intrinsics: {exc}") from None
    check_output_file(args.out, "OUT.npz")
    progress = Progress(f"rendering {args.split}", args.frames)
    ds = generate(args.split, args.frames, args.seed, intrinsics, progress=progress.update)
    progress.done()
    path = save_dataset(ds, args.out)
    subjects = ", ".join(sorted(set(ds.subject)))
    print(f"wrote {path}: {len(ds)} frames ({intrinsics.width}x{intrinsics.height}), subjects {subjects}, "
          f"distances {ds.distance_m.min():.2f}-{ds.distance_m.max():.2f} m")
    return 0
