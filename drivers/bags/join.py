"""A bounded join of streams: the parts of one frame (by frame number or header stamp) arriving on several topics,
paired as they come; a key whose parts do not all arrive is given up and its parts counted as unpaired."""

from __future__ import annotations

from collections import Counter
from collections.abc import Collection, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

MAX_PENDING = 64
"""Keys waiting for their other parts; past it the oldest is given up (bags interleave the messages of one frame
closely, so this only bounds the memory of the images held)."""


class StreamJoin(Generic[K, V]):
    """Pairs the parts of each key from the streams `roles`. `add` returns a key's parts (role -> value) when its
    last part arrives; a second part of one role and key replaces the first, which is counted unpaired; past
    `limit` keys waiting, the oldest is given up. Unpaired parts are counted in counters["unpaired_<role>"]."""

    def __init__(self, roles: Collection[str], counters: Counter[str], limit: int = MAX_PENDING) -> None:
        self.roles, self.counters, self.limit = frozenset(roles), counters, limit
        self._pending: dict[K, dict[str, V]] = {}

    def add(self, key: K, role: str, value: V) -> dict[str, V] | None:
        """Add `role`'s part of `key`; the key's parts once all are in, else None."""
        parts = self._pending.setdefault(key, {})
        if role in parts:
            self._unpaired((role,))
        parts[role] = value
        complete = None
        if parts.keys() == self.roles:
            complete = self._pending.pop(key)
        while len(self._pending) > self.limit:
            self._unpaired(self._pending.pop(next(iter(self._pending))))
        return complete

    def finish(self) -> None:
        """Give up every key still waiting (the end of the streams)."""
        for parts in self._pending.values():
            self._unpaired(parts)
        self._pending.clear()

    def _unpaired(self, roles: Collection[str]) -> None:
        for role in roles:
            self.counters[f"unpaired_{role}"] += 1
