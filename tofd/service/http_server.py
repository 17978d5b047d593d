"""The HTTP server behind /healthz and /metrics: waitress, serving a WSGI app from one thread of its own.

waitress (Pylons' pure-Python WSGI server) parses requests in one asynchronous loop and answers complete ones from
a fixed pool of threads, so what the network does is bounded by its settings rather than by code of ours: a
connection that sends nothing for IDLE_TIMEOUT_S (an idle keep-alive, a request line never finished) is closed;
at most `max_connections` are open at once, never more than the descriptors left after RESERVED_FDS, which stay
free for the pipeline (worker restarts, shared memory, files). A new connection at that cap evicts the connection
idle the longest (none waiting for its answer), so a flood of idle connections never keeps a health probe waiting
in the kernel's backlog; only when every connection has a request in progress is the listening socket left
there, not polled, so nothing spins. Request headers are capped at MAX_HEADER_BYTES; a client that
leaves before its answer costs no line of log (waitress's socket-error and disconnect messages are silenced; its
connection-limit warning comes at most once a minute).
"""

from __future__ import annotations

import logging
import resource
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from waitress import wasyncore
from waitress.server import create_server

log = logging.getLogger(__name__)

IDLE_TIMEOUT_S = 5
"""Seconds a connection may stay silent (before its request is complete, or between keep-alive requests)."""
CHECK_INTERVAL_S = 1
"""Seconds between waitress's checks for silent connections."""
THREADS = 2
"""Threads answering complete requests (an answer takes a snapshot: well under a millisecond)."""
RESERVED_FDS = 256
"""File descriptors never given to HTTP connections: the pipeline's (workers, pipes, shared memory, outputs)."""
MAX_HEADER_BYTES = 8192
"""Largest request head (request line and headers) read, bytes."""
BACKLOG = 64
"""Connections the kernel queues while the server is at its limit."""

WsgiApp = Callable[[dict, Callable], Iterable[bytes]]

LIMIT_WARNING_INTERVAL_S = 60.0
"""Seconds between two warnings that the server is at its connection limit."""


class _QuietWaitress(logging.Filter):
    """Lets through waitress's errors, and its warnings at most once per LIMIT_WARNING_INTERVAL_S (it warns each
    time the connection limit is reached again)."""

    def __init__(self) -> None:
        super().__init__()
        self._last_warning = -LIMIT_WARNING_INTERVAL_S

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            return True
        if record.levelno < logging.WARNING or time.monotonic() - self._last_warning < LIMIT_WARNING_INTERVAL_S:
            return False
        self._last_warning = time.monotonic()
        return True


logging.getLogger("waitress").addFilter(_QuietWaitress())  # no line per disconnect, one per minute at the limit
logging.getLogger("waitress.queue").setLevel(logging.ERROR)  # no line per request waiting for a thread


def connection_limit(wanted: int) -> int:
    """`wanted`, or fewer so that RESERVED_FDS descriptors stay free under this process's RLIMIT_NOFILE."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return wanted
    return max(1, min(wanted, soft - RESERVED_FDS))


def _evict_idle_at_the_cap(server: Any, limit: int) -> None:
    """Make waitress's server `server` accept a connection at `limit` open ones by closing the one idle the longest
    (no request in progress, no answer being sent; oldest last_activity), in its own loop thread, just before it
    accepts. Uses waitress's public attributes active_channels, channel.requests / total_outbufs_len /
    last_activity / handle_close() and server.handle_accept, pinned by tests/service/test_http_server.py."""
    accept = server.handle_accept

    def handle_accept() -> None:
        if len(server.active_channels) >= limit:
            idle = [channel for channel in server.active_channels.values()
                    if not channel.requests and not channel.total_outbufs_len]
            if idle:
                min(idle, key=lambda channel: channel.last_activity).handle_close()
        accept()

    server.handle_accept = handle_accept


class HttpServer:
    """Serves `app` on (bind, port) from a thread (port 0: a free port, see .port); OSError if it cannot listen."""

    def __init__(self, bind: str, port: int, app: WsgiApp, max_connections: int) -> None:
        self._map: dict = {}
        self.max_connections = connection_limit(max_connections)
        self._server = create_server(  # waitress's own limit counts its listener and trigger, and one more connection
            # than ours: at ours, the eviction makes room before it accepts
            app, map=self._map, host=bind, port=port, threads=THREADS, connection_limit=self.max_connections + 3,
            channel_timeout=IDLE_TIMEOUT_S, cleanup_interval=CHECK_INTERVAL_S, backlog=BACKLOG,
            max_request_header_size=MAX_HEADER_BYTES, max_request_body_size=0, log_socket_errors=False,
            expose_tracebacks=False, asyncore_use_poll=True, ident="tofd")
        _evict_idle_at_the_cap(self._server, self.max_connections)
        self.bind, self.port = str(self._server.effective_host), int(self._server.effective_port)
        self._thread = threading.Thread(target=self._server.run, name="tofd-http", daemon=True)

    def start(self) -> HttpServer:
        self._thread.start()
        return self

    def close(self, timeout_s: float = 2.0) -> None:
        """Close the listening socket and every connection, stop the server's threads.

        The closing runs in the server's own loop, woken by waitress's trigger; when the trigger is gone (waitress
        closes it with its listener after an error in its loop) or the loop does not answer within `timeout_s`, it
        runs here, and the loop, which polls at most every second, ends on its empty map."""
        if self._thread.is_alive():
            try:
                self._server.trigger.pull_trigger(lambda: wasyncore.close_all(self._map, ignore_all=True))
            except OSError:
                pass
            else:
                self._thread.join(timeout_s)
        if self._map:
            wasyncore.close_all(self._map, ignore_all=True)
            self._thread.join(timeout_s)
        self._server.task_dispatcher.shutdown(timeout=timeout_s)
