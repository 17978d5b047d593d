"""Run the pipeline as a service: wire the viewer process, the pipeline, the health endpoint, signals and
sd_notify together, and bound the shutdown.

Shared by `tofd run` (live camera) and `tofd replay` (recording). SIGTERM/SIGINT stop the capture, drain the
queues (at most pipeline.drain_timeout_s, and half of pipeline.shutdown_timeout_s), then give the viewer the
rest of shutdown_timeout_s to flush before it is killed: the process exits within shutdown_timeout_s of the
signal, summary written, whatever the Rerun SDK does. The exit code is 0 unless the pipeline failed.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

from drivers.source import FrameSource
from tofd.config import Config, ConfigError, config_digest
from tofd.progress import Progress
from tofd.service.health import HealthServer, ServiceMetrics, sd_notify
from tofd.service.model import load_service_model, model_identity
from tofd.service.pipeline.core import Pipeline, Sink
from tofd.service.pipeline.queues import Policy
from tofd.service.signals import StopSignals
from tofd.service.summary import run_summary, write_json_atomic
from tofd.service.supervise import show_progress, supervise
from tofd.service.viewer.spec import RERUN_SPEC_HELP, parse_rerun_spec

__all__ = ["RERUN_SPEC_HELP", "Progress", "ServiceResult", "parse_rerun_spec", "serve"]

log = logging.getLogger(__name__)

EXIT_MARGIN_S = 1.0  # seconds of shutdown_timeout_s kept for what follows the viewer's flush


@dataclass(slots=True)
class ServiceResult:
    exit_code: int
    summary: dict  # ledger summary + final snapshot
    web_url: str | None = None


def run_identity(cfg: Config) -> dict[str, str]:
    """What this run computes with (logged at start; labels of tofd_build_info; in the summary): the model's
    resolved path and SHA-256 and the config's digest."""
    model = model_identity(cfg)
    log.info("model: %s (sha256 %s, variant %s)", model.path or "none", model.sha256[:16] or "-",
             cfg.detector.variant)
    return {"model_path": model.path, "model_sha256": model.sha256, "config_sha256": config_digest(cfg)}


def _health(cfg: Config, pipeline: Pipeline, metrics: ServiceMetrics) -> HealthServer | None:
    if not cfg.health.enabled:
        return None
    try:
        health = HealthServer(cfg.health.bind, cfg.health.port, pipeline.snapshot, lambda: pipeline.running,
                              cfg.health.stale_after_s, metrics).start()
    except OSError as exc:
        raise ConfigError(f"health.port: cannot listen on {cfg.health.bind}:{cfg.health.port}: "
                          f"{exc.strerror}") from None
    log.info("health: http://%s:%d/healthz and /metrics", health.bind, health.port)
    return health


def serve(cfg: Config, source: FrameSource, policy: Policy, *, live_source: bool,
          writers: tuple[Sink, ...] = (), max_frames: int | None = None, progress: Progress | None = None,
          summary_path: Path | None = None) -> ServiceResult:
    """Run `source` through the pipeline until it ends, `max_frames` were taken, or SIGTERM/SIGINT."""
    from tofd.service.viewer.process import ViewerProcess

    pc = cfg.pipeline
    health = pipeline = viewer = None
    run_s, started_s, viewer_report = 0.0, time.monotonic(), None
    identity = run_identity(cfg)
    with StopSignals() as stop:
        try:
            viewer = None if cfg.rerun.sink == "none" else ViewerProcess(cfg, cfg.rerun.sink)
            metrics = ServiceMetrics(lambda: pipeline.snapshot(), identity)
            pipeline = Pipeline(cfg, policy, viewer=viewer, writers=(*writers, metrics.observe),
                                model=load_service_model(cfg), live_source=live_source)
            health = _health(cfg, pipeline, metrics)
            pipeline.start(source, max_frames)
            started_s = time.monotonic()
            sd_notify("READY=1")
            if viewer is not None and viewer.web_url:
                log.info("web viewer: %s", viewer.web_url)
            supervise(pipeline, stop, progress)
            if not stop:
                pipeline.wait(pc.drain_timeout_s)
            run_s = time.monotonic() - started_s
        finally:
            sd_notify("STOPPING=1")
            deadline = (stop.first_at_s or time.monotonic()) + pc.shutdown_timeout_s
            summary = {}
            if pipeline is not None:
                drain = min(pc.drain_timeout_s, max(0.0, (deadline - time.monotonic()) / 2))
                summary = pipeline.close(drain)
            if health is not None:
                health.close()
            if viewer is not None:
                # EXIT_MARGIN_S of the budget is left for killing the viewer and the interpreter's exit
                viewer_report = viewer.close(max(0.5, deadline - time.monotonic() - EXIT_MARGIN_S))
    snap = pipeline.snapshot()
    summary = run_summary(summary, snap, run_s, viewer_report)
    summary["model"] = {"path": identity["model_path"], "sha256": identity["model_sha256"]}
    summary["config_sha256"] = identity["config_sha256"]
    if progress is not None:
        show_progress(progress, snap)
        progress.done()
    if summary_path is not None:
        write_json_atomic(summary_path, summary)
    return ServiceResult(1 if pipeline.error else 0, summary, viewer.web_url if viewer else None)
