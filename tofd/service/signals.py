"""SIGTERM/SIGINT as a stop request the service polls, instead of an exception at a random point."""

from __future__ import annotations

import signal
import time


class StopSignals:
    """Context manager: while active, SIGTERM and SIGINT are recorded (`received`, `first_at_s`, monotonic)
    and nothing else happens; the previous handlers come back on exit."""

    SIGNALS = (signal.SIGTERM, signal.SIGINT)

    def __init__(self) -> None:
        self.received: list[int] = []  # the handler only appends: it may interrupt any code, holding any lock
        self.first_at_s: float | None = None
        self._previous: dict = {}

    def _handle(self, signum: int, _frame: object) -> None:
        if self.first_at_s is None:
            self.first_at_s = time.monotonic()
        self.received.append(signum)

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
