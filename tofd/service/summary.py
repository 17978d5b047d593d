"""The run summary: the drop ledger plus the final statistics, written atomically as JSON."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TypedDict

from tofd.outputs import write_text
from tofd.service.pipeline.ledger import LedgerSummary
from tofd.service.pipeline.monitor import PipelineSnapshot


class ViewerReport(TypedDict, total=False):
    """ViewerProcess.close's report: how the viewer process ended ("clean", "killed", or "cancelled" while it
    started), frames it logged, frames Rerun refused, frames handed over but not logged; for a "save" sink the
    .rrd's name (path), where its readable part is (output: path, its partial name, or None) and why it could not
    be finished (failed)."""

    exit: str
    frames: int
    errors: int
    unsent: int
    path: str
    output: str | None
    failed: str


class ModelRecord(TypedDict):
    path: str
    sha256: str


class RunSummary(LedgerSummary):
    """The run summary (<stem>.summary.json): the ledger summary, fps over the whole run, timing quantiles (ms,
    p50 and p99 per stage), worker restarts, device events, the error if any, the nose track's counts (None: no
    detector), the outputs that failed (file -> why), the viewer's end report (None: no viewer), the model and
    config the run used, the shutdown's report (tofd.service.shutdown) and the Foxglove viewer process's end
    report (None: no Foxglove server)."""

    error: str | None
    fps: float
    timings_ms: dict[str, list[float]]
    worker_restarts: int
    device_events: dict[str, int]
    track: dict[str, str | float | int | tuple[float, float, float] | None] | None
    outputs_failed: dict[str, str]
    viewer: ViewerReport | None
    model: ModelRecord
    config_sha256: str
    shutdown: dict[str, object]
    foxglove: ViewerReport | None


def run_summary(ledger_summary: LedgerSummary, snap: PipelineSnapshot, run_s: float, viewer: ViewerReport | None,
                model: ModelRecord, config_sha256: str, shutdown: dict[str, object],
                foxglove: ViewerReport | None = None) -> RunSummary:
    """The run summary of a run of `run_s` seconds (see RunSummary)."""
    return RunSummary(
        **ledger_summary, error=snap.error,
        fps=round(ledger_summary["frames_out"] / run_s, 2) if run_s > 0 else 0.0,
        timings_ms={k: [round(x, 3) for x in v] for k, v in snap.timings_ms.items()},
        worker_restarts=snap.worker_restarts, device_events=dict(snap.device_events),
        track=None if snap.track is None else dataclasses.asdict(snap.track),
        outputs_failed={**snap.outputs_failed,
                        **({viewer["path"]: viewer["failed"]} if viewer and viewer.get("failed") else {})},
        viewer=viewer, model=model,
        config_sha256=config_sha256, shutdown=shutdown, foxglove=foxglove)


def write_json_atomic(path: Path, data: object) -> None:
    """Write `data` as JSON to `path` atomically (tofd.outputs), creating its directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(data, indent=1) + "\n")
