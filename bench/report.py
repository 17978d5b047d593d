"""Shared parts of the benchmarks: model and sequence arguments, and the JSON they write (and say where)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tofd.algorithm.detector import Candidates, Margin, NoseDetector, NoseModel
    from tofd.config import Config
    from tofd.service.pipeline import Pipeline


def write_json(path: str | Path, results: dict) -> Path:
    """Write results as indented JSON (creating the directory) and print the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {path}")
    return path


def shown_path(path: str | Path) -> str:
    """A path as results show it: relative to the repository when inside it (no machine's checkout in the docs)."""
    resolved, root = Path(path).resolve(), Path(__file__).resolve().parents[1]
    return str(resolved.relative_to(root)) if resolved.is_relative_to(root) else str(path)


def run_to_end(pipeline: Pipeline, seconds: float | None) -> float:
    """Seconds from now until the started `pipeline` ends: at its source's end, or stopped after `seconds`."""
    t0 = time.monotonic()
    if seconds is not None:
        time.sleep(seconds)
        pipeline.stop()
    pipeline.wait()
    return time.monotonic() - t0


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """--model (default: the shipped config/nose_model.json) and --config (default config/tofd.toml)."""
    parser.add_argument("--model", default=str(Path(__file__).parents[1] / "config" / "nose_model.json"))
    parser.add_argument("--config", default=None, help="config file (default config/tofd.toml)")


def model_setup(args: argparse.Namespace) -> tuple[Config, Candidates, Margin, NoseModel]:
    """The config of --config, its detector's candidates and margin test, and the --model file checked against it."""
    from tofd.algorithm.detector import Candidates, Margin, load_model
    from tofd.config import load_config

    cfg = load_config(args.config)
    model = load_model(args.model)
    model.check_compatible(cfg.features, cfg.segmentation)
    return cfg, Candidates.from_config(cfg.detector, cfg.segmentation), Margin.from_config(cfg.detector), model


def add_sequence_arguments(parser: argparse.ArgumentParser) -> None:
    """--model, --config, --frames and --conditions of the head-motion sequence benches (tofd.lab.sequences)."""
    add_model_arguments(parser)
    parser.add_argument("--frames", type=int, default=240, help="frames per sequence (20 fps)")
    parser.add_argument("--conditions", default="train_sensor,noise_x2,dark_face",
                        help="comma-separated sensor conditions (tofd.lab.conditions) or 'all'")


def sequence_detector(args: argparse.Namespace, prog: str) -> tuple[tuple[str, ...], Config, NoseDetector]:
    """The parsed --conditions (SystemExit naming `prog` if one is unknown), the config and its detector."""
    from tofd.algorithm.detector import NoseDetector, load_model  # here: the other benches need none of it
    from tofd.config import load_config
    from tofd.lab.conditions import parse_conditions

    try:
        conditions = parse_conditions(args.conditions)
    except ValueError as exc:
        raise SystemExit(f"{prog}: --conditions: {exc}") from None
    cfg = load_config(args.config)
    return conditions, cfg, NoseDetector(load_model(args.model), cfg.detector, cfg.features, cfg.segmentation,
                                    cfg.intrinsics)
