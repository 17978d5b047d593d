"""Faults for the chaos tests and bench/chaos.py: a TCP peer that never reads, free ports, metrics polling,
`tofd` subprocesses, /dev/shm segments, processes by parent."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


class BlackHole:
    """A TCP server on 127.0.0.1 that accepts every connection and never reads from it (a stalled viewer)."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.port = self.sock.getsockname()[1]
        self.accepted: list[socket.socket] = []
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.accepted.append(conn)

    def close(self) -> None:
        self.sock.close()
        for c in self.accepted:
            c.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


TERMINAL_SIGNALS = (signal.SIGHUP, signal.SIGINT, signal.SIGQUIT)
"""Stop signals a shell starts a job with ignored (SIGHUP under nohup; SIGINT and SIGQUIT in the background)."""


def default_stop_signals() -> None:
    """A child's preexec_fn: TERMINAL_SIGNALS at their default disposition, as under a terminal, however the tests
    were started (a child inherits an ignored signal, and tofd keeps a stop signal it started with ignored)."""
    for sig in TERMINAL_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


def tofd(*args: object, **kwargs: object) -> subprocess.Popen:
    """A `tofd` child with pipes, the stop signals at their defaults unless `preexec_fn` says otherwise."""
    kwargs.setdefault("preexec_fn", default_stop_signals)
    env = {**os.environ, "RUST_LOG": "error", **kwargs.pop("env", {})}
    return subprocess.Popen([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, **kwargs)


def health_port(proc: subprocess.Popen) -> tuple[int, list[str]]:
    """The /healthz port a `tofd run --health-port 0` logs, read from its stderr, and the lines read up to it (an
    assertion error with them if the process ends first)."""
    lines: list[str] = []
    while not any("INFO health:" in line for line in lines):
        lines.append(proc.stderr.readline())
        assert lines[-1], "".join(lines)
    return int(next(line for line in lines if "INFO health:" in line).split(":")[-1].split("/")[0]), lines


def healthz(port: int, timeout_s: float = 5) -> tuple[int, dict]:
    """The /healthz status code and JSON status of the daemon on `port` (a 503 is an answer too)."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=timeout_s) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def metrics(port: int) -> str:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as resp:
            return resp.read().decode()
    except (urllib.error.URLError, OSError):
        return ""


def metric(text: str, name: str, labels: str = "") -> float:
    """The value of one sample (labels as in the exposition, e.g. '{reason="blocked"}'); 0 if absent."""
    m = re.search(rf"^{re.escape(name + labels)} (\S+)$", text, re.M)
    return float(m.group(1)) if m else 0.0


def wait_for(predicate, timeout_s: float, poll_s: float = 0.2) -> bool:
    """Poll `predicate` until true or `timeout_s` passed (a guard against hangs, not a speed check)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return False


def shm_segments(prefix: str = "tofd_") -> set[str]:
    return {p.name for p in Path("/dev/shm").glob(prefix + "*")}


def children_of(pid: int) -> list[int]:
    """Pids whose parent is `pid` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def tree(pid: int) -> list[int]:
    """`pid` and all its descendants."""
    out, todo = [pid], [pid]
    while todo:
        kids = children_of(todo.pop())
        out.extend(kids)
        todo.extend(kids)
    return out


def workers_of(pid: int) -> list[int]:
    """The feature worker processes of a tofd process: its children that map the workers' shared-memory slot
    ring (the viewer maps its own, the resource tracker none), by pid."""
    out = []
    for kid in sorted(children_of(pid)):
        try:
            maps = Path(f"/proc/{kid}/maps").read_text()
        except OSError:
            continue
        if f"/dev/shm/tofd_{pid}_workers_" in maps:
            out.append(kid)
    return out


def alive(pid: int) -> bool:
    """True if `pid` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
