"""Shared tail of the benchmarks: write the results as JSON and say where."""

from __future__ import annotations

import json
from pathlib import Path


def write_json(path: str | Path, results: dict) -> Path:
    """Write results as indented JSON (creating the directory) and print the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {path}")
    return path
