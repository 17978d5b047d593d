"""Run the pipeline as a service: viewer sink, detector, health endpoint, signals, sd_notify, progress.

Shared by `tofd run` (live camera) and `tofd replay` (recording). SIGTERM/SIGINT stop the capture and
drain the queues (bounded by pipeline.drain_timeout_s); the exit code is 0 unless the pipeline failed.
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

from drivers.source import FrameSource
from tofd.config import RERUN_SINKS, Config, ConfigError
from tofd.service.health import HealthServer, sd_notify, watchdog_interval_s
from tofd.service.model import load_service_model
from tofd.service.pipeline.core import Pipeline, Sink
from tofd.service.pipeline.queues import Policy

log = logging.getLogger(__name__)

RERUN_SPEC_HELP = "save:PATH | web | connect:URL | spawn | none (default: the config's [rerun] sink)"


def parse_rerun_spec(spec: str | None, cfg: Config) -> Config:
    """Apply a --rerun value (see RERUN_SPEC_HELP) to the [rerun] section; ConfigError names a bad one."""
    if spec is None:
        return cfg
    kind, _, arg = spec.partition(":")
    if kind == "save" and arg:
        return replace(cfg, rerun=replace(cfg.rerun, sink="save", path=arg))
    if kind == "connect":
        return replace(cfg, rerun=replace(cfg.rerun, sink="connect", url=arg or cfg.rerun.url))
    if kind in RERUN_SINKS and not arg:
        return replace(cfg, rerun=replace(cfg.rerun, sink=kind))
    raise ConfigError(f"--rerun: {spec!r} is not one of {RERUN_SPEC_HELP}")


@dataclass(slots=True)
class ServiceResult:
    exit_code: int
    summary: dict  # ledger summary + final snapshot
    web_url: str | None = None


class Progress:
    """A one-line progress bar on stderr (redrawn in place on a terminal, a line per 10 % otherwise)."""

    def __init__(self, total: int | None, label: str):
        self.total, self.label, self._tty = total, label, sys.stderr.isatty()
        self._last_decile = -1

    def update(self, snap: dict, final: bool = False) -> None:
        done = snap["frames_out"] + snap["frames_dropped"]
        if self.total:
            frac = min(1.0, done / self.total)
            bar = "#" * int(frac * 30)
            text = f"{self.label} [{bar:<30}] {done}/{self.total} frames"
            decile = int(frac * 10)
        else:
            text, decile = f"{self.label} {done} frames", done // 100
        text += f"  {snap['fps']:.1f} fps  dropped {snap['frames_dropped']}"
        if self._tty:
            sys.stderr.write("\r" + text + ("\n" if final else ""))
        elif decile != self._last_decile or final:
            sys.stderr.write(text + "\n")
        self._last_decile = decile
        sys.stderr.flush()


def serve(cfg: Config, source: FrameSource, policy: Policy, *, live_source: bool,
          writers: tuple[Sink, ...] = (), max_frames: int | None = None, progress: Progress | None = None,
          summary_path: Path | None = None) -> ServiceResult:
    """Run `source` through the pipeline until it ends, `max_frames` were taken, or SIGTERM/SIGINT."""
    from tofd.service.viewer import RerunLogger, RerunTarget

    target = None if cfg.rerun.sink == "none" else RerunTarget(cfg.rerun, cfg.rerun.sink)
    stop: list[int] = []  # signals received; the handler must not take locks (it can interrupt anything)
    previous = {sig: signal.signal(sig, lambda signum, _: stop.append(signum)) for sig in (signal.SIGTERM,
                                                                                         signal.SIGINT)}
    health = pipeline = None
    run_s = 0.0
    try:
        viewer = RerunLogger(target.rec, cfg.intrinsics, cfg.rerun.point_cloud) if target else None
        pipeline = Pipeline(cfg, policy, viewer=viewer, writers=writers, model=load_service_model(cfg),
                            live_source=live_source)
        if cfg.health.enabled:
            try:
                health = HealthServer(cfg.health.bind, cfg.health.port, pipeline.snapshot,
                                      lambda: pipeline.running, cfg.health.stale_after_s).start()
            except OSError as exc:
                raise ConfigError(f"health.port: cannot listen on {cfg.health.bind}:{cfg.health.port}: "
                                  f"{exc.strerror}") from None
            log.info("health: http://%s:%d/healthz and /metrics", health.bind, health.port)
        pipeline.start(source, max_frames)
        started_s = time.monotonic()
        sd_notify("READY=1")
        if target is not None and target.web_url:
            log.info("web viewer: %s", target.web_url)
        _supervise(pipeline, stop, progress)
        pipeline.wait(cfg.pipeline.drain_timeout_s)
        run_s = time.monotonic() - started_s
    finally:
        sd_notify("STOPPING=1")
        summary = pipeline.close() if pipeline is not None else {}
        if health is not None:
            health.close()
        if target is not None:
            target.close(cfg.pipeline.drain_timeout_s)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    snap = pipeline.snapshot()
    summary["error"] = pipeline.error
    summary["fps"] = round(summary["frames_out"] / run_s, 2) if run_s > 0 else 0.0  # over the whole run
    summary["timings_ms"] = {k: [round(x, 3) for x in v] for k, v in snap["timings_ms"].items()}
    summary["worker_restarts"] = pipeline.worker_restarts
    summary["device_events"] = dict(snap["device_events"])
    if progress is not None:
        progress.update(snap, final=True)
    if summary_path is not None:
        summary_path.parent.mkdir(parents=True, exist_ok=True)
        summary_path.write_text(json.dumps(summary, indent=1) + "\n")
    return ServiceResult(1 if pipeline.error else 0, summary, target.web_url if target else None)


def _supervise(pipeline: Pipeline, stop: list[int], progress: Progress | None) -> None:
    """Wait for the end of the run, pinging the systemd watchdog while the pipeline works, drawing progress."""
    watchdog = watchdog_interval_s()
    tick = min(0.25, watchdog or 0.25)
    last_ping = 0.0
    while pipeline.running:
        time.sleep(tick)
        if stop:
            log.info("%s: draining the pipeline", signal.Signals(stop[0]).name)
            pipeline.stop()
            return
        if watchdog is not None and time.monotonic() - last_ping >= watchdog:
            if pipeline.error is None:  # alive and not failed; a camera that is away (reconnecting) is no reason
                sd_notify("WATCHDOG=1")  # for systemd to restart us: /healthz reports that to monitoring instead
            last_ping = time.monotonic()
        if progress is not None:
            progress.update(pipeline.snapshot())
