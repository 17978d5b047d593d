"""The /healthz and /metrics HTTP server under a hostile network, over real sockets on 127.0.0.1: silent and half-sent
requests are closed, connections are capped and descriptors kept for the pipeline, early leavers cost no log line."""

from __future__ import annotations

import logging
import os
import resource
import socket
import struct
import time
import urllib.request

import pytest

from tofd.service.http_server import IDLE_TIMEOUT_S, RESERVED_FDS, HttpServer, connection_limit
from tofd_testing.chaos_helpers import health_port


def _app(environ, start_response):
    body = b"ok\n"
    start_response("200 OK", [("Content-Type", "text/plain"), ("Content-Length", str(len(body)))])
    return [body]


@pytest.fixture
def server():
    srv = HttpServer("127.0.0.1", 0, _app, max_connections=4).start()
    yield srv
    srv.close()


def _get(port: int, timeout: float = 30) -> bytes:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=timeout) as resp:
        return resp.read()


def _closed_by_server(sock: socket.socket, timeout: float) -> bool:
    """Whether the server closes `sock` (EOF or reset) within `timeout` seconds."""
    sock.settimeout(timeout)
    try:
        while sock.recv(4096):
            pass
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False
    return True


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.slow
def test_silent_and_half_sent_requests_are_closed_while_others_are_answered(server):
    idle = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(2)]
    half = socket.create_connection(("127.0.0.1", server.port))
    half.sendall(b"GET /healthz\r\n")  # a request line without its version, never finished
    try:
        assert _get(server.port) == b"ok\n"  # answered meanwhile (one slot of the four left)
        for sock in [*idle, half]:
            assert _closed_by_server(sock, IDLE_TIMEOUT_S * 6)
    finally:
        for sock in [*idle, half]:
            sock.close()


@pytest.mark.slow
def test_connections_beyond_the_cap_wait_in_the_backlog_and_hold_no_descriptor(server):
    before = _open_fds()
    held = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(4 + 20)]
    try:
        time.sleep(0.5)  # let the server accept what it will
        server_side = _open_fds() - before - len(held)  # descriptors the server opened for them
        assert server_side <= 4
        assert _closed_by_server(held[0], IDLE_TIMEOUT_S * 6)  # the silent ones time out, the next are taken
    finally:
        for sock in held:
            sock.close()
    assert _get(server.port) == b"ok\n"


def test_clients_that_leave_before_their_answer_cost_no_log_line(caplog):
    server = HttpServer("127.0.0.1", 0, _app, max_connections=32).start()
    with caplog.at_level(logging.DEBUG):
        for _ in range(50):
            sock = socket.create_connection(("127.0.0.1", server.port))
            sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # reset, not FIN
            sock.close()
        assert _get(server.port) == b"ok\n"
    server.close()
    assert [r for r in caplog.records if r.levelno > logging.DEBUG] == []


def test_descriptors_are_kept_for_the_pipeline():
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (RESERVED_FDS + 40, hard))
        assert connection_limit(1000) == 40
        assert connection_limit(8) == 8
        resource.setrlimit(resource.RLIMIT_NOFILE, (RESERVED_FDS - 10, hard))
        assert connection_limit(8) == 1
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_close_ends_open_connections_and_frees_the_port():
    srv = HttpServer("127.0.0.1", 0, _app, max_connections=4).start()
    port = srv.port
    sock = socket.create_connection(("127.0.0.1", port))
    srv.close()
    assert _closed_by_server(sock, 5)
    sock.close()
    with socket.socket() as probe:
        assert probe.connect_ex(("127.0.0.1", port)) != 0


def test_close_holds_when_waitress_has_closed_its_trigger():
    """waitress closes its wake-up pipe with its listener after an error in its loop; close still ends the server."""
    srv = HttpServer("127.0.0.1", 0, _app, max_connections=4).start()
    port = srv.port
    sock = socket.create_connection(("127.0.0.1", port))
    assert _get(port) == b"ok\n"
    srv._server.trigger.close()
    srv.close()
    assert _closed_by_server(sock, 5)
    sock.close()
    assert not srv._thread.is_alive()
    with socket.socket() as probe:
        assert probe.connect_ex(("127.0.0.1", port)) != 0


def test_waitress_has_what_the_eviction_uses():
    """Pins the waitress attributes tofd.service.http_server's eviction reads and calls."""
    from waitress.channel import HTTPChannel

    srv = HttpServer("127.0.0.1", 0, _app, max_connections=4).start()
    try:
        sock = socket.create_connection(("127.0.0.1", srv.port))
        deadline = time.monotonic() + 30
        while not srv._server.active_channels and time.monotonic() < deadline:
            time.sleep(0.05)
        (channel,) = srv._server.active_channels.values()
        assert isinstance(channel, HTTPChannel) and channel.requests == [] and channel.total_outbufs_len == 0
        assert isinstance(channel.last_activity, float) and callable(channel.handle_close)
        sock.close()
    finally:
        srv.close()


def test_a_flood_of_idle_connections_evicts_the_oldest_and_a_probe_is_answered(server):
    """At the cap (4 here) each new connection closes the one idle the longest: the first ones are closed long
    before waitress's idle timeout, and a probe behind 30 idle connections is answered."""
    held = []
    try:
        for _ in range(30):
            held.append(socket.create_connection(("127.0.0.1", server.port)))
            time.sleep(0.01)  # an order of arrival
        assert _get(server.port, timeout=IDLE_TIMEOUT_S) == b"ok\n"  # before any could have timed out
        assert _closed_by_server(held[0], 0.5)  # evicted, not timed out
    finally:
        for sock in held:
            sock.close()


@pytest.mark.slow
def test_healthz_answers_while_300_idle_connections_are_held_at_a_descriptor_limit_of_300(tmp_path):
    from tofd_testing.chaos_helpers import default_stop_signals, healthz, tofd
    from tofd_testing.pipeline_sources import write_config

    def limited() -> None:
        default_stop_signals()
        resource.setrlimit(resource.RLIMIT_NOFILE, (300, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))

    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--health-port", "0", "--rerun", "none",
                preexec_fn=limited)
    held = []
    try:
        port, lines = health_port(proc)
        deadline = time.monotonic() + 120
        while healthz(port)[0] != 200 and time.monotonic() < deadline:
            time.sleep(0.5)
        for _ in range(300):
            held.append(socket.create_connection(("127.0.0.1", port)))
        codes = []
        for _ in range(5):  # each probe answered before an idle connection could have timed out
            t0 = time.monotonic()
            codes.append(healthz(port, timeout_s=IDLE_TIMEOUT_S)[0])
            print(f"/healthz answered in {time.monotonic() - t0:.3f} s with 300 idle connections held")
        assert codes == [200] * 5 and proc.poll() is None
    finally:
        for sock in held:
            sock.close()
        proc.send_signal(15)
        proc.communicate(timeout=120)
