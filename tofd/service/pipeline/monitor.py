"""The pipeline's state at one moment (PipelineSnapshot), for /metrics, /healthz, progress lines, systemd's
status and the run summary."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from tofd.service.pipeline.ledger import DropLedger
from tofd.service.pipeline.pool import WorkerPool
from tofd.service.pipeline.stats import PipelineStats, TrackSnapshot


@dataclass(frozen=True, slots=True)
class PipelineSnapshot:
    """Counters, rates, timings, queue depths, the nose track and the failed outputs of a running (or finished)
    pipeline."""

    frames_in: int
    frames_out: int
    frames_dropped: int
    drops: Mapping[tuple[str, str], int]  # (stage, reason class) -> frames dropped (DropLedger.drops_by)
    viewer_drops: Mapping[str, int]  # reason class -> delivered frames the viewer did not get
    gaps: int  # device-side gaps (counter jumps, reconnects)
    fps: float  # delivered frames per second over the last 5 s
    timings_ms: Mapping[str, tuple[float, ...]]  # stage -> (p50, p99) in milliseconds over the rolling window
    queue_depth: Mapping[str, int]  # queue -> frames waiting in it ("workers": frames being processed)
    workers_alive: int
    worker_restarts: int
    device_events: Mapping[str, int]  # kind (e.g. "reconnect") -> events counted by the driver
    last_delivery_age_s: float | None  # seconds since the last delivered frame (None before the first)
    error: str | None  # the pipeline's fatal error, if any
    track: TrackSnapshot | None  # None without a detector
    outputs_failed: Mapping[str, str] = field(default_factory=dict)  # output file -> why it failed (written no more)


def snapshot(ledger: DropLedger, stats: PipelineStats, pool: WorkerPool, queue_depth: Mapping[str, int],
             device_events: Mapping[str, int], error: str | None, track: TrackSnapshot | None,
             outputs_failed: Mapping[str, str] | None = None) -> PipelineSnapshot:
    """The snapshot of the pipeline's parts now."""
    return PipelineSnapshot(
        frames_in=ledger.frames_in, frames_out=ledger.frames_out, frames_dropped=ledger.frames_dropped,
        drops=ledger.drops_by(), viewer_drops=ledger.viewer_drops_by(), gaps=ledger.gap_count, fps=stats.fps(),
        timings_ms=stats.quantiles_ms(), queue_depth={**queue_depth, "workers": pool.inflight},
        workers_alive=pool.alive(), worker_restarts=pool.restarts, device_events=dict(device_events),
        last_delivery_age_s=stats.last_delivery_age_s(), error=error, track=track,
        outputs_failed=dict(outputs_failed or {}))
