"""Logging setup of the `tofd` command: every line carries its level; under systemd, journald reads it too.

On a terminal: `tofd: WARNING message`. When stderr goes to the journal ($JOURNAL_STREAM is set by systemd), each
line starts with the sd-daemon priority prefix (`<4>` = warning), so `journalctl -p warning` filters by level.
"""

from __future__ import annotations

import logging
import os
import sys

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
