"""The main thread's job while the pipeline runs: watch for a stop signal, ping the systemd watchdog,
draw progress."""

from __future__ import annotations

import logging
import time

from tofd.progress import Progress
from tofd.service.health import notify_status, sd_notify, status_text, watchdog_interval_s
from tofd.service.pipeline import Pipeline
from tofd.service.pipeline.monitor import PipelineSnapshot
from tofd.service.signals import StopSignals

log = logging.getLogger(__name__)


def supervise(pipeline: Pipeline, stop: StopSignals, progress: Progress | None) -> None:
    """Return as soon as the pipeline ended (the run's time, hence its fps, ends there), or when a stop signal
    came (then capture is stopped; draining is the caller's); log a status line for each SIGUSR1. The watchdog is
    pinged only while the pipeline has not failed; a camera that is away (reconnecting) is no reason for systemd to
    restart us: /healthz reports that to monitoring instead."""
    watchdog = watchdog_interval_s()
    tick = min(0.25, watchdog or 0.25)
    last_ping, status_requests = 0.0, 0
    while not pipeline.wait(tick):  # a sleep of `tick` would round a short run's time up to the next tick
        if stop.status_requests != status_requests:  # SIGUSR1
            status_requests = stop.status_requests
            log.info("status: %s", status_text(pipeline.snapshot()))
        if stop:
            log.info("%s: draining the pipeline", stop.name)
            pipeline.stop()
            return
        if watchdog is not None and time.monotonic() - last_ping >= watchdog:
            if pipeline.error is None:
                sd_notify("WATCHDOG=1")
            notify_status(pipeline.snapshot())
            last_ping = time.monotonic()
        if progress is not None:
            show_progress(progress, pipeline.snapshot())


def show_progress(progress: Progress, snap: PipelineSnapshot) -> None:
    """Move the progress bar to the frames delivered or dropped so far, with fps and drops."""
    progress.update(snap.frames_out + snap.frames_dropped, status=f"{snap.fps:.1f} fps, dropped {snap.frames_dropped}")
