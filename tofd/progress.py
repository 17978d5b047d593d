"""The one progress bar of every command: tqdm on stderr, drawn only when stderr is a terminal."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm


class Progress:
    """A bar of `total` frames (None: a counter); update() moves it to an absolute count, done() closes it."""

    def __init__(self, label: str, total: int | None = None, unit: str = "frames") -> None:
        self.start = time.monotonic()
        self.count = 0
        self._bar = tqdm(total=total, desc=label, unit=f" {unit}", file=sys.stderr, dynamic_ncols=True,
                         disable=not sys.stderr.isatty(), leave=True, mininterval=0.25)

    def update(self, count: int, total: int | None = None, status: str | None = None) -> None:
        """Set the bar to `count` (of `total`, if it changed); `status` is shown after the rate."""
        if total is not None and total != self._bar.total:
            self._bar.total = total
        if status is not None:
            self._bar.set_postfix_str(status, refresh=False)
        self._bar.update(count - self.count)
        self.count = count

    def done(self) -> float:
        """Close the bar; returns the elapsed seconds."""
        self._bar.close()
        return time.monotonic() - self.start
