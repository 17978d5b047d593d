"""The run summary: the drop ledger plus the final statistics, written atomically as JSON."""

from __future__ import annotations

import json
from pathlib import Path

from tofd.outputs import write_text


def run_summary(ledger_summary: dict, snap: dict, run_s: float, viewer: dict | None) -> dict:
    """`ledger_summary` (DropLedger.summary) with fps over the whole run, timing quantiles (ms), worker
    restarts, device events, the error if any, the nose track's counts (None: no detector) and the viewer's end
    report (None: no viewer)."""
    return {**ledger_summary,
            "error": snap["error"],
            "fps": round(ledger_summary["frames_out"] / run_s, 2) if run_s > 0 else 0.0,
            "timings_ms": {k: [round(x, 3) for x in v] for k, v in snap["timings_ms"].items()},
            "worker_restarts": snap["worker_restarts"],
            "device_events": dict(snap["device_events"]),
            "track": snap["track"],
            "outputs_failed": {**snap.get("outputs_failed", {}),
                               **({viewer["path"]: viewer["failed"]}
                                  if viewer and viewer.get("failed") else {})},
            "viewer": viewer}


def write_json_atomic(path: Path, data: dict) -> None:
    """Write `data` as JSON to `path` atomically (tofd.outputs), creating its directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(data, indent=1) + "\n")
