"""tofd's exceptions above the drivers: TofdError (the root, from tofd.drivers.errors) carries the exit status `tofd`
ends with; UsageError and ConfigError are a user's mistakes (exit status 2)."""

from __future__ import annotations

from tofd.drivers.errors import DataError, DriverError, TofdError

__all__ = ["ConfigError", "DataError", "DriverError", "TofdError", "UsageError"]


class UsageError(TofdError, ValueError):
    """A mistake of the user's: a bad argument, a missing or malformed input file, an unusable output path.

    `tofd` prints `tofd <command>: <message>` and exits 2; the message names the argument or file and the problem.
    """

    exit_status = 2


class ConfigError(UsageError):
    """A config file that cannot be used; the message names the offending key. `tofd` prints
    `tofd <command>: config error: <message>`."""


def input_error(path: object, exc: BaseException) -> UsageError:
    """A UsageError for input file `path` that could not be read because of `exc`, naming the path once (a
    reader's message usually names it already)."""
    text = str(exc)
    return UsageError(text if str(path) in text else f"{path}: {text}")
