"""Size and time limits of the live .rrd file: numbered segments, the oldest deleted beyond a count.

With `[rerun] rotate_mb` or `rotate_s` set, a live run's "save" sink writes <stem>.00000.rrd, <stem>.00001.rrd, ...
beside `path` (a replay's file, with its footer, is one), starting the next segment once the current one holds
rotate_mb megabytes or rotate_s seconds, and keeps the newest `keep_files` (0: all). Every segment is a complete
recording with the same recording id, so `rerun <stem>.*.rrd` shows them as one. Sizes are checked against what the
SDK has written, which it does in batches (targets.FILE_BATCHER): a segment ends up to one batch past rotate_mb.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from tofd.config import RerunConfig

CHECK_EVERY_S = 0.5  # seconds between looks at the current segment's size


class FileRotation:
    """Which segment the .rrd file sink writes and when the next one starts (see the module docstring)."""

    def __init__(self, cfg: RerunConfig):
        base = Path(cfg.path)
        self.base, self.max_bytes, self.max_s, self.keep = base, int(cfg.rotate_mb * 1e6), cfg.rotate_s, cfg.keep_files
        self.index = 0
        self.opened_s = self._checked_s = time.monotonic()

    @staticmethod
    def wanted(cfg: RerunConfig, sink: str, footer: bool) -> bool:
        """Whether the sink is a live file (no footer: a lossless replay's .rrd is one complete recording) with a
        size or time limit."""
        return sink == "save" and not footer and (cfg.rotate_mb > 0 or cfg.rotate_s > 0)

    def segment(self, index: int | None = None) -> Path:
        """The path of segment `index` (the current one by default)."""
        n = self.index if index is None else index
        return self.base.with_name(f"{self.base.name.removesuffix('.rrd')}.{n:05d}.rrd")

    def due(self) -> bool:
        """Whether the current segment reached its size or age limit."""
        now = time.monotonic()
        if self.max_s > 0 and now - self.opened_s >= self.max_s:
            return True
        if self.max_bytes <= 0 or now - self._checked_s < CHECK_EVERY_S:
            return False
        self._checked_s = now
        try:
            return os.path.getsize(self.segment()) >= self.max_bytes
        except OSError:
            return False

    def advance(self) -> Path:
        """Start the next segment (its path); delete the ones beyond the newest keep_files, counting it."""
        self.index += 1
        self.opened_s = self._checked_s = time.monotonic()
        if self.keep > 0 and self.index >= self.keep:
            self.segment(self.index - self.keep).unlink(missing_ok=True)
        return self.segment()

    def describe(self) -> str:
        """What the segments are, for the run's log."""
        limits = [f"{self.max_bytes / 1e6:g} MB"] if self.max_bytes > 0 else []
        limits += [f"{self.max_s:g} s"] if self.max_s > 0 else []
        kept = f"the newest {self.keep} kept" if self.keep > 0 else "all kept"
        return (f"{self.segment(0)}, {self.segment(1).name}, ... ({' or '.join(limits)} each, {kept}; "
                "[rerun] rotate_mb = 0 and rotate_s = 0: one file)")
