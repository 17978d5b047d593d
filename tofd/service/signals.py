"""What each signal does to tofd, in one place.

- SIGTERM, SIGINT (Ctrl-C), SIGHUP (the terminal or session went away; `systemctl kill -s HUP`) and SIGQUIT
  (Ctrl-\\): stop. A running service drains its queues, writes its summary and exits 0 within
  pipeline.shutdown_timeout_s; a second one changes nothing. Before the service is up (tofd still loading) the
  command ends with one line, `tofd COMMAND: interrupted (SIGxxx)`, and exit status 130 (`tofd run` while it
  opens the camera: one line, exit 0).
- A stop signal the process was started with ignored (SIGHUP under `nohup`) stays ignored.
- SIGUSR1: log one status line (frames, fps, drops by reason) and go on; ignored while tofd loads.
- Worker and viewer processes ignore all of these (the parent decides when they stop) from the moment they are
  started (`children_start` holds the signals back meanwhile), and so does multiprocessing's resource tracker
  (`start_resource_tracker`): a signal a terminal sends to the whole process group never kills a child or
  prints its traceback.
"""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Callable, Iterator

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGQUIT)
"""Signals that stop tofd."""
STATUS_SIGNAL = signal.SIGUSR1
"""The signal that logs a status line."""
CHILD_IGNORED = frozenset({*STOP_SIGNALS, STATUS_SIGNAL})
"""Signals a worker or viewer process ignores (its parent stops it through its pipe, or kills it)."""


class Interrupted(KeyboardInterrupt):
    """A stop signal while tofd loads (before a service took the signals over): the command ends, exit 130."""


def _interrupt(signum: int, _frame: object) -> None:
    raise Interrupted(signal.Signals(signum).name)


_IGNORED_AT_START = frozenset(sig for sig in STOP_SIGNALS if signal.getsignal(sig) == signal.SIG_IGN)
"""Stop signals this process was started with ignored (e.g. SIGHUP under nohup): they stay ignored."""


def interrupt_while_loading() -> None:
    """From process start until a service installs StopSignals: every stop signal raises Interrupted (SIGINT
    too, named), SIGUSR1 is ignored. Call first thing in the main thread."""
    for sig in STOP_SIGNALS:
        if sig not in _IGNORED_AT_START:
            signal.signal(sig, _interrupt)
    signal.signal(STATUS_SIGNAL, signal.SIG_IGN)


def ignore_in_child() -> None:
    """In a freshly started worker or viewer process: ignore CHILD_IGNORED, then let through what
    `children_start` held back (it is then discarded)."""
    for sig in CHILD_IGNORED:
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, CHILD_IGNORED)


@contextlib.contextmanager
def children_start() -> Iterator[None]:
    """Around starting a child process: CHILD_IGNORED are blocked in this thread, so the child starts with them
    blocked (the mask is inherited) until its ignore_in_child; signals for this process wait, none is lost."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, CHILD_IGNORED)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (the process that unlinks shared memory a crashed owner left) under
    `children_start`, before anything registers with it: it ignores SIGINT and SIGTERM itself, and keeps the other
    CHILD_IGNORED blocked, so a terminal's SIGHUP or SIGQUIT to the process group does not kill it (its successor
    would print a traceback for every segment it never saw). `ensure_running` is the module's public entry."""
    from multiprocessing import resource_tracker

    with children_start():
        resource_tracker.ensure_running()


class StopSignals:
    """Context manager: while active, STOP_SIGNALS are recorded (`received`, `first_at_s`, monotonic) and, if
    given, passed to `on_signal(signum, first)`; SIGUSR1 counts up `status_requests`. The previous handlers come
    back on exit.

    `on_signal` runs in the handler and may interrupt any code, so it keeps to printing, starting a thread or
    raising (e.g. to end a blocking call that polls no stop request)."""

    SIGNALS = tuple(sig for sig in STOP_SIGNALS if sig not in _IGNORED_AT_START)

    def __init__(self, on_signal: Callable[[int, bool], None] | None = None) -> None:
        self.received: list[int] = []  # the handler only appends: it may interrupt any code, holding any lock
        self.first_at_s: float | None = None
        self.status_requests = 0  # SIGUSR1s so far (the supervisor logs a status line for each new one)
        self._on_signal = on_signal
        self._previous: dict = {}

    def _handle(self, signum: int, _frame: object) -> None:
        first = self.first_at_s is None
        if first:
            self.first_at_s = time.monotonic()
        self.received.append(signum)
        if self._on_signal is not None:
            self._on_signal(signum, first)

    def _status(self, _signum: int, _frame: object) -> None:
        self.status_requests += 1

    def __enter__(self) -> StopSignals:
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        self._previous[STATUS_SIGNAL] = signal.signal(STATUS_SIGNAL, self._status)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return bool(self.received)

    @property
    def name(self) -> str:
        return signal.Signals(self.received[0]).name if self.received else ""
