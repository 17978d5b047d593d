"""The pipeline's state as one JSON-ready dict, for /metrics, progress lines and the run summary."""

from __future__ import annotations

from collections.abc import Mapping

from tofd.service.pipeline.ledger import DropLedger
from tofd.service.pipeline.pool import WorkerPool
from tofd.service.pipeline.stats import PipelineStats


def snapshot(ledger: DropLedger, stats: PipelineStats, pool: WorkerPool, queue_depth: Mapping[str, int],
             device_events: Mapping[str, int], error: str | None, track: dict | None,
             outputs_failed: Mapping[str, str] | None = None) -> dict:
    """Counters, rates, timings (ms quantiles), queue depths, the nose track (stats.TrackStats.snapshot, None
    without a detector) and the outputs that failed (file -> why); see tofd.service.health for the metrics."""
    return {
        "frames_in": ledger.frames_in,
        "frames_out": ledger.frames_out,
        "frames_dropped": ledger.frames_dropped,
        "drops": ledger.drops_by(),
        "viewer_drops": ledger.viewer_drops_by(),
        "gaps": len(ledger.gaps),
        "fps": stats.fps(),
        "timings_ms": stats.quantiles_ms(),
        "queue_depth": {**queue_depth, "workers": pool.inflight},
        "workers_alive": pool.alive(),
        "worker_restarts": pool.restarts,
        "device_events": dict(device_events),
        "last_delivery_age_s": stats.last_delivery_age_s(),
        "error": error,
        "track": track,
        "outputs_failed": dict(outputs_failed or {}),
    }
