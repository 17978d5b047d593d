"""Command-line plumbing shared by `tofd train` and `tofd evaluate`: data arguments, loading or rendering the
default split, and feature extraction with progress on stderr."""

from __future__ import annotations

import argparse
import time

from tofd.config import Config
from tofd.lab.dataset import Dataset, load_labelled
from tofd.lab.evaluation import FrameSamples, extract_samples
from tofd.progress import Progress

DEFAULT_FRAMES = {"train": 120, "test": 960}  # test: 120 per distance, EER steps of 0.8 %


def add_data_arguments(parser: argparse.ArgumentParser, splits: tuple[str, ...]) -> None:
    for split in splits:
        parser.add_argument(f"--{split}", metavar=split.upper(), default=None,
                            help=f"{split} data: a dataset .npz or a recording with ground truth "
                                 f"(default: render the {split} split of tofd/lab/faces.py)")
        parser.add_argument(f"--{split}-frames", type=int, default=DEFAULT_FRAMES[split],
                            help=f"frames of the rendered {split} split (default {DEFAULT_FRAMES[split]})")
        parser.add_argument(f"--{split}-subjects", default=None, metavar="NAME,...",
                            help=f"subjects of the rendered {split} split, comma-separated (default: the split's; "
                                 "known: tofd.lab.faces.SUBJECTS)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the rendered splits (test uses seed + 1)")
    parser.add_argument("--config", default=None, help="config file (default config/tofd.toml)")
    parser.add_argument("--workers", type=int, default=2, help="feature-extraction processes (default 2)")
    parser.add_argument("--radius-mm", type=float, default=15.0,
                        help="true nose pixels: 3-D distance (on the 3x3-median range) to the ground-truth tip "
                             "at most this (default 15)")


def dataset_for(args: argparse.Namespace, split: str, timing: dict) -> Dataset:
    """The --<split> file, or the rendered default split; records seconds spent in timing[f'{split}_data_s']."""
    from tofd.lab.faces import generate

    start = time.monotonic()
    path = getattr(args, split)
    names = getattr(args, f"{split}_subjects")
    if path is not None:
        if names is not None:
            raise SystemExit(f"tofd: --{split}-subjects renders the {split} split; "
                             f"it cannot be combined with --{split}")
        ds = load_labelled(path)
    else:
        frames = getattr(args, f"{split}_frames")
        if frames < 1:
            raise SystemExit(f"tofd: --{split}-frames must be >= 1, got {frames}")
        subjects = tuple(n.strip() for n in names.split(",") if n.strip()) if names is not None else None
        progress = Progress(f"rendering {split} split", frames)
        try:
            ds = generate(split, frames, args.seed + (split == "test"), progress=progress.update, subjects=subjects)
        except ValueError as exc:  # names the unknown subjects (tofd.lab.faces.render_frames)
            raise SystemExit(f"tofd: --{split}-subjects: {exc}") from None
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
