"""Logging setup of the `tofd` command: every line carries its level; under systemd, journald reads it too.

On a terminal: `tofd: WARNING message`. When stderr goes to the journal ($JOURNAL_STREAM is set by systemd), each
line starts with the sd-daemon priority prefix (`<4>` = warning), so `journalctl -p warning` filters by level.
"""

from __future__ import annotations

import logging
import os
import sys
import time

LEVELS = ("debug", "info", "warning", "error")

# syslog priorities of sd-daemon(3) prefixes
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        return f"<{_PRIORITY.get(record.levelno, 6)}>{super().format(record)}"


def on_journal() -> bool:
    """True when stderr is the journal stream systemd set up for this service."""
    stream = os.environ.get("JOURNAL_STREAM", "")
    if not stream or ":" not in stream:
        return False
    try:
        st = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError):
        return False
    return stream == f"{st.st_dev}:{st.st_ino}"


def setup_logging(level: str = "info") -> None:
    """Route the root logger to stderr at `level` (one of LEVELS), replacing earlier handlers."""
    handler = logging.StreamHandler(sys.stderr)
    if on_journal():
        handler.setFormatter(_JournalFormatter("%(levelname)s %(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("tofd: %(levelname)s %(message)s"))
    root = logging.getLogger()
    for old in root.handlers[:]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(level.upper())
    if level != "debug":  # third-party chatter stays at warning unless debugging
        for name in ("matplotlib", "PIL", "urllib3", "numba"):
            logging.getLogger(name).setLevel(logging.WARNING)


def root_level() -> str:
    """The root logger's level as one of LEVELS (for setup_logging in a child process)."""
    level = logging.getLogger().getEffectiveLevel()
    return next((name for name in LEVELS if logging.getLevelName(name.upper()) >= level), "error")



class LimitedLines(logging.Filter):
    """Prefixes each record with `prefix` and lets at most `burst` records through per `interval_s` seconds (a
    library that logs a line per item of one bad request cannot flood the log); the first record let through after
    some were left out says how many."""

    def __init__(self, prefix: str, burst: int = 5, interval_s: float = 60.0):
        super().__init__()
        self.prefix, self.burst, self.interval_s = prefix, burst, interval_s
        self._window_start = -interval_s
        self._passed = self._left_out = 0

    def filter(self, record: logging.LogRecord) -> bool:
        now = time.monotonic()
        if now - self._window_start >= self.interval_s:
            self._window_start, self._passed = now, 0
        if self._passed >= self.burst:
            self._left_out += 1
            return False
        self._passed += 1
        note = f" ({self._left_out} more lines left out before this one)" if self._left_out else ""
        record.msg, record.args, self._left_out = f"{self.prefix}{record.getMessage()}{note}", (), 0
        return True


class _ToRoot(logging.Handler):
    """Hands a record to the root logger's handlers (tofd's format), after this handler's filters."""

    def emit(self, record: logging.LogRecord) -> None:
        logging.getLogger().handle(record)


def limit_library_lines(name: str, prefix: str, burst: int = 5, interval_s: float = 60.0) -> None:
    """Route logger `name` and its children (a library's, e.g. a Rust SDK's bridged logging) through one
    LimitedLines filter to the root logger's handlers, from WARNING up unless the root logs at DEBUG."""
    library = logging.getLogger(name)
    if any(isinstance(h, _ToRoot) for h in library.handlers):
        return
    handler = _ToRoot()
    handler.addFilter(LimitedLines(prefix, burst, interval_s))
    library.addHandler(handler)
    library.propagate = False
    if logging.getLogger().getEffectiveLevel() > logging.DEBUG:
        library.setLevel(logging.WARNING)
