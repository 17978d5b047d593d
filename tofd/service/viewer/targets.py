"""Where the Rerun stream goes: an .rrd file, a running viewer, or a viewer child process we start.

The Python SDK's serve_grpc/serve_web_viewer/spawn listen on 0.0.0.0 and have no bind argument, so the
"web" and "spawn" sinks start the `rerun` CLI as a child process with `--bind` (127.0.0.1 by default) and
connect to it over gRPC. Rerun's log calls can block while a connected viewer stalls; the pipeline only
calls them from its sink thread, behind a queue that drops (live) instead of blocking the capture path.
"""

from __future__ import annotations

import importlib.util
import os
import socket
import subprocess
import tempfile
import time
import uuid
from pathlib import Path

import rerun as rr

from tofd.config import RerunConfig
from tofd.service.lifeline import preexec_die_with_parent
from tofd.service.viewer.blueprint import build_blueprint
from tofd.service.viewer.process import ViewerError

APPLICATION_ID = "tofd"
# A file sink batches large chunks (few seconds, up to 64 MiB of rows) so `rerun rrd stats` finds the .rrd
# optimised; viewers keep the SDK's low-latency default.
FILE_BATCHER_FLUSH_TICK_S, FILE_BATCHER_FLUSH_BYTES, FILE_BATCHER_FLUSH_ROWS = 5.0, 64 << 20, 100_000
QUIET_NO_FOOTER = "warn,re_log_encoding::rrd::file_sink=error"  # RUST_LOG: no warning that a file has no footer


def file_footer(policy: str) -> bool:
    """Whether the .rrd file sink writes Rerun's footer (its chunk index, for fast random access): for lossless
    runs (replays) only. The SDK keeps the index in memory until the file closes, so a live run's would grow for
    as long as it runs; the viewer reads a file without it by scanning."""
    return policy == "lossless"


def apply_analytics_setting(enabled: bool) -> None:
    """Honour [rerun] analytics for this process and the viewer children it starts: unless enabled, set CI=1,
    the variable under which the Rerun SDK and viewer neither collect nor send usage data."""
    if not enabled:
        os.environ["CI"] = "1"


def rerun_executable() -> str:
    """The native `rerun` binary shipped in rerun-sdk's rerun_cli package.

    Not the `rerun` console script: that Python shim runs the binary as ITS child, which would outlive a
    terminate() of the shim.
    """
    spec = importlib.util.find_spec("rerun_cli")
    binary = Path(spec.origin).with_name("rerun") if spec and spec.origin else None
    if binary is None or not binary.exists():
        raise ViewerError("the rerun viewer binary was not found (it ships with rerun-sdk, package rerun_cli)")
    return str(binary)


def port_open(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex((host, port)) == 0


def _client_host(bind: str) -> str:
    return "127.0.0.1" if bind in ("0.0.0.0", "") else bind


class RerunTarget:
    """A RecordingStream connected to the configured sink, and the viewer child process if we started one.

    `sink`: "save" (cfg.path or `path`; `footer`: see file_footer), "connect" (cfg.url), "web" or "spawn" (child
    viewer on cfg.bind). `image_shape`: the camera's (rows, columns), for the blueprint.
    """

    def __init__(self, cfg: RerunConfig, sink: str, image_shape: tuple[int, int], path: str | None = None,
                 url: str | None = None, recording_id: str | None = None, start_timeout_s: float = 20.0,
                 footer: bool = True):
        self.cfg, self.sink = cfg, sink
        self.child: subprocess.Popen | None = None
        self.web_url: str | None = None
        apply_analytics_setting(cfg.analytics)
        batcher = rr.ChunkBatcherConfig(flush_tick=FILE_BATCHER_FLUSH_TICK_S, flush_num_bytes=FILE_BATCHER_FLUSH_BYTES,
                                        flush_num_rows=FILE_BATCHER_FLUSH_ROWS) if sink == "save" else None
        self.rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or str(uuid.uuid4()),
                                      batcher_config=batcher)
        blueprint = build_blueprint(image_shape)
        if sink == "save":
            Path(path or cfg.path).parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(path or cfg.path, default_blueprint=blueprint, write_footer=footer)
        elif sink == "connect":
            self.rec.connect_grpc(url or cfg.url, default_blueprint=blueprint)
        elif sink in ("web", "spawn"):
            host = _client_host(cfg.bind)
            args = ["--bind", cfg.bind, "--port", str(cfg.grpc_port), "--memory-limit", cfg.memory_limit]
            if sink == "web":
                args += ["--serve-web", "--web-viewer-port", str(cfg.web_port),
                         "--server-memory-limit", cfg.memory_limit]
            self._start_child(args, host, start_timeout_s)
            grpc_url = f"rerun+http://{host}:{cfg.grpc_port}/proxy"
            if sink == "web":
                quoted = grpc_url.replace(":", "%3A").replace("/", "%2F").replace("+", "%2B")
                self.web_url = f"http://{host}:{cfg.web_port}/?url={quoted}"
            self.rec.connect_grpc(grpc_url, default_blueprint=blueprint)
        else:
            raise ValueError(f"sink: {sink!r} is not one of 'save', 'connect', 'web', 'spawn'")

    def _start_child(self, args: list[str], host: str, timeout_s: float) -> None:
        for port in (self.cfg.grpc_port, self.cfg.web_port if self.sink == "web" else None):
            if port is not None and port_open(host, port):
                raise ViewerError(f"port {port} on {host} is already in use (rerun.grpc_port / rerun.web_port)")
        self._child_log = tempfile.TemporaryFile()  # a file, not a pipe: a full pipe would stall the viewer
        # own session: a Ctrl-C or a signal to our process group must not kill the viewer before we drain
        self.child = subprocess.Popen([rerun_executable(), *args], stdin=subprocess.DEVNULL,
                                      stdout=subprocess.DEVNULL, stderr=self._child_log, start_new_session=True,
                                      preexec_fn=preexec_die_with_parent)  # no orphan viewer after a kill -9
        deadline = time.monotonic() + timeout_s
        while not port_open(host, self.cfg.grpc_port):
            if self.child.poll() is not None:
                self._child_log.seek(0)
                err = self._child_log.read().decode(errors="replace").strip().splitlines()[-3:]
                raise ViewerError(f"the rerun viewer exited with code {self.child.returncode}"
                                  f" (no display for `spawn`?): {' | '.join(err)}")
            if time.monotonic() > deadline:
                self.close(0)
                raise ViewerError(f"the rerun viewer did not listen on {host}:{self.cfg.grpc_port} "
                                  f"in {timeout_s:g} s")
            time.sleep(0.1)

    def close(self, flush_timeout_s: float = 5.0) -> None:
        """Flush (bounded), disconnect, and stop a child viewer we started (SIGTERM, then SIGKILL)."""
        try:
            self.rec.flush(timeout_sec=flush_timeout_s)
        except RuntimeError:
            pass  # an unreachable gRPC sink: what is still queued is lost, as Rerun reports
        self.rec.disconnect()
        if self.child is not None and self.child.poll() is None:
            self.child.terminate()
            try:
                self.child.wait(5)
            except subprocess.TimeoutExpired:
                self.child.kill()
                self.child.wait(5)
