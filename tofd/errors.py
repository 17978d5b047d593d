"""The exceptions a command turns into one line on stderr and exit status 2 (a usage, config or data mistake)."""

from __future__ import annotations


class UsageError(ValueError):
    """A mistake of the user's: a bad argument, a missing or malformed input file, an unusable output path.

    `tofd` prints `tofd: <message>` and exits 2; the message names the argument or file and the problem.
    """


class ConfigError(UsageError):
    """A config file that cannot be used; the message names the offending key. `tofd` prints
    `tofd <command>: config error: <message>`."""


def input_error(path: object, exc: BaseException) -> UsageError:
    """A UsageError for input file `path` that could not be read because of `exc`, naming the path once (a
    reader's message usually names it already)."""
    text = str(exc)
    return UsageError(text if str(path) in text else f"{path}: {text}")
