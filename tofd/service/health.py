"""Health endpoint (/healthz, Prometheus /metrics; served by tofd.service.http_server) and systemd notifications
(sd_notify).

/healthz answers 200 while the pipeline runs, has no fatal error and delivered a frame within
`stale_after_s`, else 503; the body is a small JSON status (HEAD answers the same status without it): "ok",
"starting" (503: no frame delivered yet, so a probe does not call a camera that never sent one healthy),
"unhealthy", or "degraded" (still 200) while an output has failed (a full disk, a permission; named in its problems
and in tofd_output_failed). /metrics is ServiceMetrics through prometheus_client.
sd_notify writes READY=1 / WATCHDOG=1 / STATUS= / STOPPING=1 datagrams to $NOTIFY_SOCKET with a plain socket;
without that variable it does nothing.
"""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Callable, Iterable, Iterator
from http import HTTPStatus
from typing import TYPE_CHECKING

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Histogram, Info, ProcessCollector
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import generate_latest

import tofd
from tofd.algorithm.tracking import STATUSES
from tofd.service.http_server import HttpServer

if TYPE_CHECKING:
    from tofd.service.pipeline.monitor import PipelineSnapshot
    from tofd.service.pipeline.results import FrameResult
    from tofd.service.pipeline.stats import TrackSnapshot

Snapshot = Callable[[], "PipelineSnapshot"]


def sd_notify(message: str) -> bool:
    """Send one notification (e.g. "READY=1") to systemd; False when not run by systemd (no NOTIFY_SOCKET)."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):  # abstract namespace socket
        address = "\0" + address[1:]
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
        sock.sendto(message.encode(), address)
    return True


def watchdog_interval_s() -> float | None:
    """Half of systemd's WatchdogSec (from $WATCHDOG_USEC, if meant for this process), else None."""
    usec, pid = os.environ.get("WATCHDOG_USEC"), os.environ.get("WATCHDOG_PID")
    if not usec or (pid and int(pid) != os.getpid()):
        return None
    return int(usec) / 2e6


STAGE_BUCKETS_S = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5)


def _unlabelled(family: type, name: str, help_text: str, value: float) -> Metric:
    """One counter or gauge family without labels, holding `value`."""
    m = family(name, help_text)
    m.add_metric([], float(value))
    return m


class _SnapshotCollector:
    """Counters and gauges read from Pipeline.snapshot() at scrape time."""

    def __init__(self, snapshot: Snapshot) -> None:
        self._snapshot = snapshot

    def collect(self) -> Iterator[Metric]:
        snap = self._snapshot()
        one = _unlabelled
        yield one(CounterMetricFamily, "tofd_frames_in", "Frames that entered the pipeline.", snap.frames_in)
        yield one(CounterMetricFamily, "tofd_frames_out", "Frames delivered to every sink.", snap.frames_out)
        dropped = CounterMetricFamily("tofd_frames_dropped", "Frames dropped, by stage and reason.",
                                      labels=["stage", "reason"])
        for (stage, reason), n in sorted(snap.drops.items()):
            dropped.add_metric([stage, reason], float(n))
        yield dropped
        viewer = CounterMetricFamily("tofd_viewer_frames_dropped",
                                     "Delivered frames the best-effort viewer did not get, by reason.",
                                     labels=["reason"])
        for reason, n in sorted(snap.viewer_drops.items()):
            viewer.add_metric([reason], float(n))
        yield viewer
        yield one(GaugeMetricFamily, "tofd_fps", "Delivered frames per second (last 5 s).", snap.fps)
        # a summary (a quantile label on a gauge fails `promtool check metrics`): the quantiles of the rolling
        # window; the run's counts and sums per stage are the histogram tofd_stage_duration_seconds'
        rolling = Metric("tofd_stage_duration_rolling_seconds", "Per-frame stage durations over the rolling "
                         "window (pipeline.stats_window frames), by quantile.", "summary")
        for stage, quantiles in sorted(snap.timings_ms.items()):
            for q, v in zip(("0.5", "0.99"), quantiles, strict=True):
                rolling.add_sample(rolling.name, {"stage": stage, "quantile": q}, v / 1e3)
        yield rolling
        depth = GaugeMetricFamily("tofd_queue_depth", "Frames waiting in each queue (workers: being processed).",
                                  labels=["queue"])
        for q, n in snap.queue_depth.items():
            depth.add_metric([q], float(n))
        yield depth
        yield one(CounterMetricFamily, "tofd_device_gaps", "Device-side gaps (counter jumps, reconnects).",
                  snap.gaps)
        yield one(CounterMetricFamily, "tofd_reconnects", "Camera reconnects.",
                  snap.device_events.get("reconnect", 0))
        events = CounterMetricFamily("tofd_device_events", "Device events counted by the driver, by kind.",
                                     labels=["kind"])
        for kind, n in sorted(snap.device_events.items()):
            events.add_metric([kind], float(n))
        yield events
        yield one(CounterMetricFamily, "tofd_worker_restarts", "Feature worker processes restarted.",
                  snap.worker_restarts)
        yield one(GaugeMetricFamily, "tofd_workers_alive", "Feature worker processes alive.", snap.workers_alive)
        failed = GaugeMetricFamily("tofd_output_failed", "Outputs that failed and are written no more (1), by file.",
                                   labels=["output"])
        for output in sorted(snap.outputs_failed):
            failed.add_metric([output], 1.0)
        yield failed
        if snap.track is not None:
            yield from _track_metrics(snap.track)


def _track_metrics(track: TrackSnapshot) -> Iterator[Metric]:
    """The nose track beside the per-frame detection (tofd.service.pipeline.stats.TrackStats.snapshot)."""
    one = _unlabelled
    yield one(CounterMetricFamily, "tofd_nose_detected_frames", "Frames with an accepted nose detection.",
              track.detected_frames)
    yield one(CounterMetricFamily, "tofd_nose_tip_frames", "Frames whose accepted detection was refined to a "
              "sub-pixel nose tip.", track.tip_frames)
    tip = GaugeMetricFamily("tofd_nose_tip_meters", "The last refined nose tip, camera frame, metres.", labels=["axis"])
    for axis, value in zip("xyz", track.tip_xyz_m or (), strict=False):
        tip.add_metric([axis], float(value))
    yield tip
    yield one(CounterMetricFamily, "tofd_nose_tracked_frames", "Frames with a reported nose track.",
              track.tracked_frames)
    yield one(CounterMetricFamily, "tofd_track_acquired", "Confirmed nose tracks begun (new or replacing one).",
              track.acquired)
    yield one(CounterMetricFamily, "tofd_track_lost", "Confirmed nose tracks lost without a successor.",
              track.lost)
    yield one(GaugeMetricFamily, "tofd_track_confidence", "Confidence of the nose track after the last frame (0-1).",
              track.confidence)
    status = GaugeMetricFamily("tofd_track_status", "The nose track's status after the last frame (1: current).",
                               labels=["status"])
    for name in STATUSES:
        status.add_metric([name], float(track.status == name))
    yield status


class ServiceMetrics:
    """The Prometheus registry of one service run: pipeline counters and gauges (from its snapshot), per-stage
    duration histograms (observe(), called per delivered frame), process metrics and tofd_build_info.

    `build`: labels of tofd_build_info, e.g. version, model_path, model_sha256, config_sha256.
    """

    def __init__(self, snapshot: Snapshot, build: dict[str, str] | None = None) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        ProcessCollector(registry=self.registry)
        self.registry.register(_SnapshotCollector(snapshot))
        self.stage_seconds = Histogram("tofd_stage_duration_seconds", "Per-frame stage durations.", ["stage"],
                                       buckets=STAGE_BUCKETS_S, registry=self.registry)
        Info("tofd_build", "Version of tofd and digests of the model and config it runs with.",
             registry=self.registry).info({"version": tofd.__version__, **(build or {})})

    def observe(self, result: FrameResult) -> None:
        """Record one delivered frame's stage timings (a pipeline sink: Pipeline(writers=(metrics.observe,)))."""
        for stage, ms in result.timings_ms.items():
            self.stage_seconds.labels(stage).observe(ms / 1e3)

    def render(self) -> bytes:
        """The Prometheus text exposition (CONTENT_TYPE_LATEST)."""
        return generate_latest(self.registry)


def status_text(snap: PipelineSnapshot) -> str:
    """A one-line STATUS= text for `systemctl status`: fps, frames delivered, drops by reason."""
    reasons: dict[str, int] = {}
    for (_stage, reason), n in snap.drops.items():
        reasons[reason] = reasons.get(reason, 0) + n
    drops = ", ".join(f"{r} {n}" for r, n in sorted(reasons.items()) if n)
    return (f"{snap.fps:.1f} fps, {snap.frames_out} frames delivered, {snap.frames_dropped} dropped"
            + (f" ({drops})" if drops else ""))


def notify_status(snap: PipelineSnapshot) -> bool:
    """Send STATUS=<status_text> to systemd (no-op outside systemd)."""
    return sd_notify("STATUS=" + status_text(snap))


def health_status(snap: PipelineSnapshot, running: bool, stale_after_s: float) -> tuple[bool, dict]:
    """(healthy, JSON-ready status) of a snapshot; see the module docstring."""
    age = snap.last_delivery_age_s
    problems = []
    if snap.error:
        problems.append(snap.error)
    if not running:
        problems.append("pipeline not running")
    if age is not None and age > stale_after_s:
        problems.append(f"no frame delivered for {age:.1f} s")
    failed = [f"output {output} failed: {why}" for output, why in sorted(snap.outputs_failed.items())]
    starting = not problems and snap.frames_out == 0
    status = "unhealthy" if problems else "starting" if starting else "degraded" if failed else "ok"
    return not problems and not starting, {"status": status, "problems": problems + failed,
                          "fps": round(snap.fps, 2), "frames_out": snap.frames_out,
                          "last_frame_age_s": None if age is None else round(age, 3)}


class HealthServer:
    """Serves /healthz and /metrics on (bind, port) (tofd.service.http_server: timeouts, connection cap); port 0
    picks a free port (see .port)."""

    def __init__(self, bind: str, port: int, snapshot: Snapshot, running: Callable[[], bool],
                 stale_after_s: float, metrics: ServiceMetrics | None = None, max_connections: int = 32):
        self.metrics = metrics or ServiceMetrics(snapshot)
        self._snapshot, self._running, self.stale_after_s = snapshot, running, stale_after_s
        self._http = HttpServer(bind, port, self._app, max_connections)
        self.bind, self.port = self._http.bind, self._http.port

    def _app(self, environ: dict, start_response: Callable) -> Iterable[bytes]:
        """The WSGI app: GET or HEAD of /healthz, /metrics; 404 elsewhere."""
        path = environ.get("PATH_INFO", "")
        if path == "/metrics":
            code, content_type, data = 200, CONTENT_TYPE_LATEST, self.metrics.render()
        elif path == "/healthz":
            ok, status = self.status()
            code, content_type, data = 200 if ok else 503, "application/json", (json.dumps(status) + "\n").encode()
        else:
            code, content_type, data = 404, "text/plain", b"not found: try /healthz or /metrics\n"
        start_response(f"{code} {HTTPStatus(code).phrase}", [("Content-Type", content_type),
                                                              ("Content-Length", str(len(data)))])
        return [b"" if environ.get("REQUEST_METHOD") == "HEAD" else data]

    def status(self) -> tuple[bool, dict]:
        return health_status(self._snapshot(), self._running(), self.stale_after_s)

    def start(self) -> HealthServer:
        self._http.start()
        return self

    def close(self) -> None:
        self._http.close()
