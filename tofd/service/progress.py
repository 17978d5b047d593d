"""A one-line progress bar of a pipeline run on stderr, drawn from Pipeline.snapshot()."""

from __future__ import annotations

import sys


class Progress:
    """Redrawn in place on a terminal, a line per 10 % otherwise."""

    def __init__(self, total: int | None, label: str):
        self.total, self.label, self._tty = total, label, sys.stderr.isatty()
        self._last_decile = -1

    def update(self, snap: dict, final: bool = False) -> None:
        done = snap["frames_out"] + snap["frames_dropped"]
        if self.total:
            frac = min(1.0, done / self.total)
            bar = "#" * int(frac * 30)
            text = f"{self.label} [{bar:<30}] {done}/{self.total} frames"
            decile = int(frac * 10)
        else:
            text, decile = f"{self.label} {done} frames", done // 100
        text += f"  {snap['fps']:.1f} fps  dropped {snap['frames_dropped']}"
        if self._tty:
            sys.stderr.write("\r" + text + ("\n" if final else ""))
        elif decile != self._last_decile or final:
            sys.stderr.write(text + "\n")
        self._last_decile = decile
        sys.stderr.flush()
