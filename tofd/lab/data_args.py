"""Command-line plumbing shared by `tofd train` and `tofd evaluate`: data arguments, loading or rendering the
default split, and feature extraction with progress on stderr."""

from __future__ import annotations

import argparse
import time

from tofd.config import Config
from tofd.drivers.intrinsics import Intrinsics
from tofd.errors import UsageError
from tofd.lab.cameras import INTRINSICS_HELP, parse_intrinsics
from tofd.lab.dataset import Dataset, load_labelled
from tofd.lab.evaluation import NOSE_RADIUS_M, FrameSamples, extract_samples
from tofd.lab.faces import SUBJECTS, parse_subjects
from tofd.progress import Progress

DEFAULT_FRAMES = {"train": 120, "test": 960}  # test: 120 per distance, EER steps of 0.8 %


def add_data_arguments(parser: argparse.ArgumentParser, splits: tuple[str, ...]) -> None:
    for split in splits:
        parser.add_argument(f"--{split}", metavar=split.upper(), default=None,
                            help=f"{split} data: a dataset .npz or a recording with ground truth "
                                 f"(default: render the {split} split)")
        parser.add_argument(f"--{split}-frames", type=int, default=DEFAULT_FRAMES[split],
                            help=f"frames of the rendered {split} split (default {DEFAULT_FRAMES[split]})")
        parser.add_argument(f"--{split}-subjects", default=None, metavar="NAME,...",
                            help=f"subjects of the rendered {split} split, comma-separated (default: the split's; "
                                 f"known: {', '.join(SUBJECTS)})")
        parser.add_argument(f"--{split}-intrinsics", default=None, metavar="CAMERA",
                            help=f"the rendered {split} split's {INTRINSICS_HELP} (train on one geometry and "
                                 "test on another for cross-camera results)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rendered splits (test uses seed + 1)")
    parser.add_argument("--config", default=None, help="config file (default: the bundled tofd.toml)")
    parser.add_argument("--workers", type=int, default=2, help="feature-extraction processes (default 2)")
    parser.add_argument("--radius-mm", type=float, default=NOSE_RADIUS_M * 1e3,
                        help="true nose pixels: 3-D distance (on the 3x3-median range) to the ground-truth tip "
                             f"at most this (default {NOSE_RADIUS_M * 1e3:g})")


def _subjects(args: argparse.Namespace, split: str) -> tuple[str, ...] | None:
    """The split's --*-subjects (None: not given); ValueError names unknown ones (faces.parse_subjects)."""
    names = getattr(args, f"{split}_subjects")
    return None if names is None else parse_subjects(names)


def check_data_arguments(args: argparse.Namespace, splits: tuple[str, ...]) -> None:
    """UsageError for a data argument that would fail only after long work (frames, subjects, file vs render)."""
    if args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    for split in splits:
        if getattr(args, split) is not None:
            for option in ("subjects", "intrinsics"):
                if getattr(args, f"{split}_{option}") is not None:
                    raise UsageError(f"--{split}-{option} renders the {split} split; it cannot be combined with "
                                     f"--{split}")
            continue
        intrinsics_for(args, split)
        frames = getattr(args, f"{split}_frames")
        if frames < 1:
            raise UsageError(f"--{split}-frames must be >= 1, got {frames}")
        try:
            _subjects(args, split)
        except ValueError as exc:
            raise UsageError(f"--{split}-subjects: {exc}") from None


def intrinsics_for(args: argparse.Namespace, split: str) -> Intrinsics:
    """The camera the rendered split is rendered with (--<split>-intrinsics; the SR3000 by default)."""
    text = getattr(args, f"{split}_intrinsics", None)
    try:
        return Intrinsics() if text is None else parse_intrinsics(text)
    except ValueError as exc:
        raise UsageError(f"--{split}-intrinsics: {exc}") from None


def dataset_for(args: argparse.Namespace, split: str, timing: dict) -> Dataset:
    """The --<split> file, or the rendered default split; records seconds spent in timing[f'{split}_data_s'].
    Call check_data_arguments first."""
    from tofd.lab.faces import generate

    start = time.monotonic()
    path = getattr(args, split)
    if path is not None:
        ds = load_labelled(path)
    else:
        frames = getattr(args, f"{split}_frames")
        progress = Progress(f"rendering {split} split", frames)
        ds = generate(split, frames, args.seed + (split == "test"), intrinsics_for(args, split),
                      progress=progress.update, subjects=_subjects(args, split))
        progress.done()
    timing[f"{split}_data_s"] = round(time.monotonic() - start, 3)
    return ds


def samples_for(ds: Dataset, cfg: Config, args: argparse.Namespace, split: str, timing: dict) -> list[FrameSamples]:
    """Features of every frame (all families) with a progress line; records seconds and frames/s in timing."""
    progress = Progress(f"features {split}", len(ds))
    samples = extract_samples(ds, cfg.features, cfg.segmentation, args.workers, progress.update)
    elapsed = progress.done()
    timing[f"{split}_features_s"] = round(elapsed, 3)
    timing[f"{split}_frames_per_s"] = round(len(ds) / max(elapsed, 1e-9), 2)
    return samples
