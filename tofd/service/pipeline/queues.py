"""Bounded stage queues with an explicit policy.

- "latest" (live): put never blocks; when the queue is full the OLDEST item is pushed out and returned to
  the caller, who records it in the drop ledger. The consumer always gets the newest frames.
- "lossless" (replay, recording): put blocks while the queue is full (backpressure up to the source); it
  gives up only when `abort` is set, returning the item it could not enqueue.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, Literal, TypeVar

T = TypeVar("T")
Policy = Literal["latest", "lossless"]


def run_policy(configured: str, live_source: bool) -> Policy:
    """The policy of a run from `[pipeline] policy` ("auto": latest-wins for a live source, lossless for a
    replay)."""
    if configured == "auto":
        return "latest" if live_source else "lossless"
    if configured not in ("latest", "lossless"):
        raise ValueError(f"pipeline.policy: {configured!r} is not one of 'auto', 'latest', 'lossless'")
    return "latest" if configured == "latest" else "lossless"


class StageQueue(Generic[T]):
    """A bounded FIFO between two pipeline threads; see the module docstring for the policies."""

    def __init__(self, policy: Policy, maxsize: int):
        if policy not in ("latest", "lossless"):
            raise ValueError(f"policy: {policy!r} is not 'latest' or 'lossless'")
        if maxsize < 1:
            raise ValueError(f"maxsize: must be >= 1, got {maxsize}")
        self.policy, self.maxsize = policy, maxsize
        self._items: deque[T] = deque()
        self._cond = threading.Condition()

    def put(self, item: T, abort: threading.Event) -> list[T]:
        """Enqueue `item`; returns the items that were dropped instead (empty when nothing was)."""
        with self._cond:
            dropped: list[T] = []
            if self.policy == "latest":
                while len(self._items) >= self.maxsize:
                    dropped.append(self._items.popleft())
            else:
                while len(self._items) >= self.maxsize:
                    if abort.is_set():
                        return [item]
                    self._cond.wait(0.1)
            self._items.append(item)
            self._cond.notify_all()
            return dropped

    def get(self, timeout: float) -> T | None:
        """The oldest item, waiting up to `timeout` seconds; None if the queue stayed empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._items, timeout):
                return None
            item = self._items.popleft()
            if len(self._items) == self.maxsize - 1:  # it was full: a lossless put may be waiting for room
                self._cond.notify_all()
            return item

    def drain(self) -> list[T]:
        """Remove and return everything queued."""
        with self._cond:
            items = list(self._items)
            self._items.clear()
            self._cond.notify_all()
            return items

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)
