"""Run the pipeline as a service: wire the viewer process, the pipeline, the health endpoint, signals and
sd_notify together, and bound the shutdown.

Shared by `tofd run` (live camera) and `tofd replay` (recording). SIGTERM/SIGINT stop the capture; then each
part gets its share of pipeline.shutdown_timeout_s (shutdown.py): the drain, the threads and workers, the
viewer's flush, and whatever does not finish in its share is killed, so the process exits within
shutdown_timeout_s of the signal, summary written (with the shutdown's phases and what was abandoned),
whatever the Rerun SDK or a worker does. A run whose source ended by itself (a replay) gives them
pipeline.finish_timeout_s instead, so that a viewer on busy cores finishes the file it was handed, cut short by a
stop signal meanwhile. The exit code is 0 unless the pipeline failed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from tofd.config import Config, ConfigError, config_digest
from tofd.drivers.source import FrameSource
from tofd.progress import Progress
from tofd.service.health import HealthServer, ServiceMetrics, sd_notify
from tofd.service.model import ModelIdentity, read_model_file, service_model
from tofd.service.pipeline.core import Pipeline, Sink, maps_read
from tofd.service.pipeline.ledger import LedgerSummary
from tofd.service.pipeline.queues import Policy
from tofd.service.shutdown import Shutdown
from tofd.service.signals import StopSignals, start_resource_tracker
from tofd.service.summary import ModelRecord, RunSummary, run_summary, write_json_atomic
from tofd.service.supervise import show_progress, supervise
from tofd.service.viewer.spec import RERUN_SPEC_HELP, parse_rerun_spec

if TYPE_CHECKING:
    from tofd.algorithm.detector import NoseModel
    from tofd.service.viewer.process import ViewerProcess

__all__ = ["RERUN_SPEC_HELP", "Progress", "ServiceResult", "parse_rerun_spec", "serve"]

log = logging.getLogger(__name__)


@dataclass(slots=True)
class ServiceResult:
    exit_code: int
    summary: RunSummary
    model: NoseModel | None  # the nose model the run used (None: it ran without one)
    web_url: str | None = None


def run_identity(cfg: Config, model: ModelIdentity) -> dict[str, str]:
    """What this run computes with (logged at start; labels of tofd_build_info; in the summary): the model's
    resolved path and SHA-256 and the config's digest."""
    log.info("model: %s (sha256 %s, variant %s)", model.path or "none", model.sha256[:16] or "-",
             cfg.detector.variant)
    return {"model_path": model.path, "model_sha256": model.sha256, "config_sha256": config_digest(cfg)}


def _health(cfg: Config, made: list[Pipeline], metrics: ServiceMetrics) -> HealthServer | None:
    """The health server, listening but not serving yet (made before any output starts: a busy port is a config
    error that leaves earlier outputs alone); it reports the pipeline `made` will hold."""
    if not cfg.health.enabled:
        return None
    try:
        return HealthServer(cfg.health.bind, cfg.health.port, lambda: made[0].snapshot(),
                            lambda: bool(made) and made[0].running, cfg.health.stale_after_s, metrics,
                            cfg.health.max_connections)
    except OSError as exc:
        raise ConfigError(f"health.port: cannot listen on {cfg.health.bind}:{cfg.health.port}: "
                          f"{exc.strerror}") from None


def _close(shutdown: Shutdown, pipeline: Pipeline | None, health: HealthServer | None,
           viewers: tuple[ViewerProcess | None, ViewerProcess | None],
           stopped: Callable[[], bool]) -> LedgerSummary | None:
    """Stop what was started, each part within its share of the shutdown budget: drain half of what is left
    (at most pipeline.drain_timeout_s), give the threads and workers a quarter of the rest before killing
    them, then the viewers (`viewers`: Foxglove's, a fifth of the rest, then Rerun's, the rest) before killing
    them, or at once when `stopped()` turns true (a stop signal while a run that reached its end waits for them);
    the ledger summary (None: no pipeline was made)."""
    summary = None
    if pipeline is not None:
        with shutdown.phase("pipeline"):
            summary = pipeline.close(min(pipeline.cfg.pipeline.drain_timeout_s, shutdown.left_s(0.5)),
                                     shutdown.left_s(0.25))
        shutdown.abandoned.extend(pipeline.abandoned)
    if health is not None:
        with shutdown.phase("health"):
            health.close()
    for viewer, share in zip(viewers, (0.2, 1.0), strict=True):
        if viewer is not None:
            part = "viewer" if viewer.name == "rerun" else viewer.name
            with shutdown.phase(part):
                report = viewer.close(shutdown.left_s(share), stopped)
            if report["exit"] == "killed":
                shutdown.abandoned.append(f"{part} ({report['exit']}, {report['unsent']} frame(s) unsent)")
    return summary


def serve(cfg: Config, source: FrameSource, policy: Policy, *, live_source: bool,
          writers: tuple[Sink, ...] = (), writers_read_maps: bool = False, max_frames: int | None = None,
          progress: Progress | None = None, summary_path: Path | None = None) -> ServiceResult:
    """Run `source` through the pipeline until it ends, `max_frames` were taken, or SIGTERM/SIGINT.

    The results `writers` get carry the viewed feature maps while a viewer runs, every computed map with
    `writers_read_maps`, else none (the mask and detection always)."""
    pc = cfg.pipeline
    health: HealthServer | None = None
    pipeline: Pipeline | None = None
    viewer: ViewerProcess | None = None
    foxglove: ViewerProcess | None = None
    ledger: LedgerSummary | None = None
    run_s, started_s = 0.0, time.monotonic()
    with StopSignals() as stop:  # from here a signal is a stop request, also while the children start
        try:
            from tofd.service.viewer.logger import frames_per_send  # these import the Rerun SDK: only when serving
            from tofd.service.viewer.process import ViewerProcess, hand_off_frames
            from tofd.service.viewer.rotation import FileRotation
            from tofd.service.viewer.targets import file_footer

            start_resource_tracker()
            model_file = read_model_file(cfg)
            identity = run_identity(cfg, model_file.identity)
            if cfg.foxglove.enabled:  # before any output is started: a busy port must leave earlier outputs alone
                from tofd.service.foxglove.spec import check_port_free

                check_port_free(cfg.foxglove)
            made: list[Pipeline] = []  # the metrics are one of the pipeline's sinks, so they come first
            metrics = ServiceMetrics(lambda: made[0].snapshot(), identity)
            health = _health(cfg, made, metrics)
            if cfg.rerun.sink != "none":
                viewer = ViewerProcess(cfg, cfg.rerun.sink, frames_per_send(cfg.rerun, policy),
                                       hand_off_frames(policy, cfg.rerun.sink), cancelled=lambda: bool(stop),
                                       footer=file_footer(policy))
            if cfg.foxglove.enabled:
                from tofd.service.foxglove.publisher import FoxglovePublisher

                foxglove = ViewerProcess(cfg, "foxglove", queue_frames=hand_off_frames(policy, "foxglove"),
                                         cancelled=lambda: bool(stop),
                                         open_backend=FoxglovePublisher, name="foxglove")
            model = service_model(cfg, model_file)
            pipeline = Pipeline(cfg, policy, viewer=viewer, writers=(*writers, metrics.observe), model=model,
                                live_source=live_source, live_viewers=() if foxglove is None else (foxglove,),
                                result_maps=maps_read(viewer is not None or foxglove is not None,
                                                      writers_read_maps))
            made.append(pipeline)
            if health is not None:
                health.start()
                log.info("health: http://%s:%d/healthz and /metrics", health.bind, health.port)
            pipeline.start(source, max_frames, cancelled=lambda: bool(stop))
            started_s = time.monotonic()
            sd_notify("READY=1")
            if viewer is not None and viewer.web_url:
                log.info("web viewer: %s", viewer.web_url)
            if viewer is not None and FileRotation.wanted(cfg.rerun, cfg.rerun.sink, file_footer(policy)):
                log.info("rerun: live recording in segments %s", FileRotation(cfg.rerun).describe())
            if foxglove is not None and foxglove.web_url:
                log.info("foxglove: %s (Foxglove: Open connection, Foxglove WebSocket; listening from the first frame "
                         "on)", foxglove.web_url)
            supervise(pipeline, stop, progress)
            if not stop:
                pipeline.wait(pc.drain_timeout_s)
            run_s = time.monotonic() - started_s
        finally:
            sd_notify("STOPPING=1")
            reason = stop.name or ("error" if pipeline is None or pipeline.error else "end")
            shutdown = Shutdown.start(reason, pc.finish_timeout_s if reason == "end" else pc.shutdown_timeout_s,
                                      stop.first_at_s)
            ledger = _close(shutdown, pipeline, health, (foxglove, viewer), lambda: reason == "end" and bool(stop))
            viewer_report = None if viewer is None else viewer.report
    assert pipeline is not None and ledger is not None  # else the try block raised
    snap = pipeline.snapshot()
    summary = run_summary(ledger, snap, run_s, viewer_report,
                          ModelRecord(path=identity["model_path"], sha256=identity["model_sha256"]),
                          identity["config_sha256"], shutdown.report(),
                          None if foxglove is None else foxglove.report)
    if progress is not None:
        show_progress(progress, snap)
        progress.done()
    if summary_path is not None:
        try:
            write_json_atomic(summary_path, summary)
        except OSError as exc:
            log.error("output %s failed: %s", summary_path, exc.strerror or exc)
            summary["outputs_failed"][str(summary_path)] = exc.strerror or str(exc)
    failed = pipeline.error is not None or bool(summary["outputs_failed"])
    return ServiceResult(1 if failed else 0, summary, model, viewer.web_url if viewer else None)
