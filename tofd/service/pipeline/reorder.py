"""The order in which finished frames leave the workers for the sink.

- "lossless" (replay): strict sequence order; a finished frame waits for every older one to be finished
  or dropped, so the results file reads exactly like the recording.
- "latest" (live): latest-wins; a finished frame goes out at once, and every older frame still being
  worked on is dropped as "late" (its result, if it ever comes, is discarded). A stalled worker
  therefore costs the frames it holds, never the output of the others. Output never goes back in time.
"""

from __future__ import annotations

import threading
from typing import Generic, TypeVar

from tofd.service.pipeline.queues import Policy

T = TypeVar("T")


class Reorderer(Generic[T]):
    """Thread-safe. `sent(seq)` when a frame goes to a worker, then exactly one of `done(seq, item)` or
    `gone(seq)` for it; `ready()` gives what may go to the sink now and the sequence numbers now late."""

    def __init__(self, policy: Policy):
        self.policy = policy
        self._lock = threading.Lock()
        self._next = 0  # lossless: the next seq to emit; latest: one past the newest emitted
        self._gone: set[int] = set()  # lossless: dropped seqs to skip
        self._done: dict[int, T] = {}
        self._working: set[int] = set()  # sent to a worker, neither done nor gone

    def sent(self, seq: int) -> None:
        with self._lock:
            self._working.add(seq)

    def unsent(self, seq: int) -> None:
        """Sending `seq` failed; it will be sent again."""
        with self._lock:
            self._working.discard(seq)

    def gone(self, seq: int) -> None:
        """`seq` was dropped before it finished (it will never be `done`)."""
        with self._lock:
            self._working.discard(seq)
            if self.policy == "lossless" and seq >= self._next:
                self._gone.add(seq)

    def done(self, seq: int, item: T) -> bool:
        """A finished frame; False if it came too late to be emitted (live: a newer one went out)."""
        with self._lock:
            self._working.discard(seq)
            if seq < self._next:
                return False
            self._done[seq] = item
            return True

    def ready(self) -> tuple[list[T], list[int]]:
        """(items to emit in this order, seqs that are now late and must be ledgered as dropped)."""
        with self._lock:
            if self.policy == "latest":
                return self._latest()
            out: list[T] = []
            while True:
                if self._next in self._gone:
                    self._gone.discard(self._next)
                elif self._next in self._done:
                    out.append(self._done.pop(self._next))
                else:
                    return out, []
                self._next += 1

    def _latest(self) -> tuple[list[T], list[int]]:
        if not self._done:
            return [], []
        newest = max(self._done)
        out = [self._done.pop(s) for s in sorted(self._done)]
        late = sorted(s for s in self._working if s < newest)
        self._working.difference_update(late)
        self._next = newest + 1
        return out, late

    @property
    def pending(self) -> int:
        """Finished frames waiting for an older one (lossless)."""
        with self._lock:
            return len(self._done)
