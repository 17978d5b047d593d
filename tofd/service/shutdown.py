"""The budget of one shutdown: a deadline shared by its parts, the time each part took and what was abandoned.

SIGTERM must end the process within `[pipeline] shutdown_timeout_s` whatever the viewer or the workers do, so
each part (drain, workers, health, viewer) gets a share of what is left and whatever does not finish in it is
killed or left behind; `report()` goes into the run summary, so an operator sees where the time went.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

EXIT_RESERVE_S = 1.0
"""Seconds of the budget (at most a fifth of it) kept for writing the summary and the interpreter's exit."""


@dataclass(slots=True)
class Shutdown:
    """`reason`: what ended the run ("SIGTERM", "SIGINT", "end", "error"); `deadline_s` is monotonic."""

    reason: str
    budget_s: float
    deadline_s: float
    phases_s: dict[str, float] = field(default_factory=dict)
    abandoned: list[str] = field(default_factory=list)

    @classmethod
    def start(cls, reason: str, budget_s: float, since_s: float | None = None) -> Shutdown:
        """A shutdown whose budget counts from `since_s` (the signal's arrival; default now)."""
        return cls(reason, budget_s, (time.monotonic() if since_s is None else since_s) + budget_s)

    @property
    def reserve_s(self) -> float:
        return min(EXIT_RESERVE_S, self.budget_s / 5)

    def left_s(self, share: float = 1.0) -> float:
        """`share` of the seconds left before the exit reserve (never negative)."""
        return max(0.0, (self.deadline_s - self.reserve_s - time.monotonic()) * share)

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time one part of the shutdown (seconds, in `phases_s`)."""
        t0 = time.monotonic()
        try:
            yield
        finally:
            self.phases_s[name] = round(time.monotonic() - t0, 3)

    def report(self) -> dict:
        """For the run summary."""
        return {"reason": self.reason, "budget_s": self.budget_s, "phases_s": dict(self.phases_s),
                "abandoned": list(self.abandoned)}
