"""Health endpoint (/healthz, Prometheus /metrics over http.server) and systemd notifications (sd_notify).

/healthz answers 200 while the pipeline runs, has no fatal error and delivered a frame within
`stale_after_s` (or is still starting), else 503; the body is a small JSON status. /metrics is the
Prometheus text format (version 0.0.4) of Pipeline.snapshot(). sd_notify writes READY=1 / WATCHDOG=1 /
STOPPING=1 datagrams to $NOTIFY_SOCKET with a plain socket; without that variable it does nothing.
"""

from __future__ import annotations

import json
import os
import socket
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

Snapshot = Callable[[], dict]


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


def _esc(value: str) -> str:
    return value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def _labels(**labels: str) -> str:
    return "{" + ",".join(f'{k}="{_esc(str(v))}"' for k, v in labels.items()) + "}" if labels else ""


def render_metrics(snap: dict) -> str:
    """Prometheus text exposition of a Pipeline.snapshot()."""
    out: list[str] = []

    def metric(name: str, kind: str, help_text: str, samples: list[tuple[dict, float]]) -> None:
        out.append(f"# HELP {name} {help_text}")
        out.append(f"# TYPE {name} {kind}")
        out.extend(f"{name}{_labels(**labels)} {float(value):.6g}" for labels, value in samples)

    metric("tofd_frames_in_total", "counter", "Frames that entered the pipeline.", [({}, snap["frames_in"])])
    metric("tofd_frames_out_total", "counter", "Frames delivered to every sink.", [({}, snap["frames_out"])])
    metric("tofd_frames_dropped_total", "counter", "Frames dropped, by stage and reason.",
           [({"stage": s, "reason": r}, n) for (s, r), n in sorted(snap["drops"].items())])
    metric("tofd_viewer_frames_dropped_total", "counter",
           "Delivered frames the best-effort viewer did not get, by reason.",
           [({"reason": r}, n) for r, n in sorted(snap.get("viewer_drops", {}).items())])
    metric("tofd_fps", "gauge", "Delivered frames per second (last 5 s).", [({}, snap["fps"])])
    metric("tofd_stage_duration_seconds", "summary", "Per-frame stage durations over the rolling window.",
           [({"stage": stage, "quantile": q}, v / 1e3)
            for stage, quantiles in sorted(snap["timings_ms"].items())
            for q, v in zip(("0.5", "0.99"), quantiles, strict=True)])
    metric("tofd_queue_depth", "gauge", "Frames waiting in each queue (workers: frames being processed).",
           [({"queue": q}, n) for q, n in snap["queue_depth"].items()])
    metric("tofd_device_gaps_total", "counter", "Device-side gaps (counter jumps, reconnects).", [({}, snap["gaps"])])
    metric("tofd_reconnects_total", "counter", "Camera reconnects.",
           [({}, snap["device_events"].get("reconnect", 0))])
    metric("tofd_device_events_total", "counter", "Device events counted by the driver, by kind.",
           [({"kind": k}, n) for k, n in sorted(snap["device_events"].items())])
    metric("tofd_worker_restarts_total", "counter", "Feature worker processes restarted.",
           [({}, snap["worker_restarts"])])
    metric("tofd_workers_alive", "gauge", "Feature worker processes alive.", [({}, snap["workers_alive"])])
    return "\n".join(out) + "\n"


def health_status(snap: dict, running: bool, stale_after_s: float) -> tuple[bool, dict]:
    """(healthy, JSON-ready status) of a snapshot; see the module docstring."""
    age = snap["last_delivery_age_s"]
    problems = []
    if snap["error"]:
        problems.append(snap["error"])
    if not running:
        problems.append("pipeline not running")
    if age is not None and age > stale_after_s:
        problems.append(f"no frame delivered for {age:.1f} s")
    return not problems, {"status": "ok" if not problems else "unhealthy", "problems": problems,
                          "fps": round(snap["fps"], 2), "frames_out": snap["frames_out"],
                          "last_frame_age_s": None if age is None else round(age, 3)}


class HealthServer:
    """Serves /healthz and /metrics on (bind, port) from a thread; port 0 picks a free port (see .port)."""

    def __init__(self, bind: str, port: int, snapshot: Snapshot, running: Callable[[], bool],
                 stale_after_s: float):
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
                path = self.path.split("?")[0]
                if path == "/metrics":
                    self._send(200, "text/plain; version=0.0.4; charset=utf-8", render_metrics(snapshot()))
                elif path == "/healthz":
                    ok, status = server.status()
                    self._send(200 if ok else 503, "application/json", json.dumps(status) + "\n")
                else:
                    self._send(404, "text/plain", "not found: try /healthz or /metrics\n")

            def _send(self, code: int, content_type: str, body: str) -> None:
                data = body.encode()
                self.send_response(code)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *args: object) -> None:  # no access log on stderr
                pass

        self._snapshot, self._running, self.stale_after_s = snapshot, running, stale_after_s
        self._httpd = ThreadingHTTPServer((bind, port), Handler)
        self._httpd.daemon_threads = True
        self.bind, self.port = self._httpd.server_address[:2]
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="tofd-health", daemon=True)

    def status(self) -> tuple[bool, dict]:
        return health_status(self._snapshot(), self._running(), self.stale_after_s)

    def start(self) -> HealthServer:
        self._thread.start()
        return self

    def close(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(2.0)
