"""SIGTERM/SIGINT as a stop request the service polls, instead of an exception at a random point."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable


class StopSignals:
    """Context manager: while active, SIGTERM and SIGINT are recorded (`received`, `first_at_s`, monotonic)
    and, if given, passed to `on_signal(signum, first)`; the previous handlers come back on exit.

    `on_signal` runs in the handler and may interrupt any code, so it keeps to printing, starting a thread or
    raising (e.g. to end a blocking call that polls no stop request)."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self, on_signal: Callable[[int, bool], None] | None = None) -> None:
        self.received: list[int] = []  # the handler only appends: it may interrupt any code, holding any lock
        self.first_at_s: float | None = None
        self._on_signal = on_signal
        self._previous: dict = {}

    def _handle(self, signum: int, _frame: object) -> None:
        first = self.first_at_s is None
        if first:
            self.first_at_s = time.monotonic()
        self.received.append(signum)
        if self._on_signal is not None:
            self._on_signal(signum, first)

    def __enter__(self) -> StopSignals:
        self._previous = {sig: signal.signal(sig, self._handle) for sig in self.SIGNALS}
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return bool(self.received)

    @property
    def name(self) -> str:
        return signal.Signals(self.received[0]).name if self.received else ""
