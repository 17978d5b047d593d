"""The root of tofd's exceptions, and the driver layer's own: each says the exit status `tofd` ends with.

`tofd` prints a TofdError as one line, `tofd <command>: <message>`, and exits with its `exit_status`: 1 for a
runtime failure (a camera, a viewer, the pipeline), 2 for a usage, config or data mistake.
"""

from __future__ import annotations

from typing import ClassVar


class TofdError(Exception):
    """An error tofd reports in one line; `exit_status` is 1 (a runtime failure) unless a subclass says 2."""

    exit_status: ClassVar[int] = 1


class DataError(TofdError, ValueError):
    """Bytes of a file or message that do not follow their format (exit status 2)."""

    exit_status = 2


class DriverError(TofdError, RuntimeError):
    """A frame source that cannot be opened or used (no device, access denied, unreadable file)."""
