"""Shared tail of the benchmarks: write the results as JSON and say where."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


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


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """--model (default: the shipped config/nose_model.json) and --config (default config/tofd.toml)."""
    parser.add_argument("--model", default=str(Path(__file__).parents[1] / "config" / "nose_model.json"))
    parser.add_argument("--config", default=None, help="config file (default config/tofd.toml)")
