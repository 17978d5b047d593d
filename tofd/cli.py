"""The `tofd` command: one subcommand per module in tofd/commands/ (each has add_arguments and main)."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
import typing

import tofd
import tofd.commands
from tofd.errors import UsageError
from tofd.logs import LEVELS, setup_logging

DESCRIPTION = """\
tofd: scale-invariant range features (Haker et al. 2008) and nose detection for SR3000-style time-of-flight
cameras. It runs as a live camera daemon (Rerun viewer, /healthz, /metrics), records and replays MCAP
recordings, and trains and evaluates the nose detector.

Exit status: 0 success, 1 runtime failure (camera, viewer, pipeline), 2 usage or data error, 130 interrupted."""

EPILOG = "Start with `tofd run --emulate --rerun web` (no camera needed), or `tofd COMMAND --help`."


class _Parser(argparse.ArgumentParser):
    """An argument mistake is one line on stderr (pointing to --help) and exit status 2."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tofd", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"tofd {tofd.__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages (same as --log-level debug)")
    parser.add_argument("--log-level", choices=LEVELS, default="info", help="lowest level logged (default info)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for name in sorted(m.name for m in pkgutil.iter_modules(tofd.commands.__path__)):
        module = importlib.import_module(f"tofd.commands.{name}")
        summary = (module.__doc__ or "").strip().splitlines()[0]
        p = sub.add_parser(name, help=summary, description=module.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(func=module.main, exit_at_once=getattr(module, "EXIT_AT_ONCE", False))
    return parser


def main(argv: list[str] | None = None, *, exit_at_once: bool = False) -> int:
    """Run one `tofd` command; its exit status. With `exit_at_once`, a command whose module sets EXIT_AT_ONCE
    (the service commands: their outputs are written and their children gone when they return) ends the
    process right away, without the interpreter's teardown of its modules (the Rerun SDK, numpy, ... take up
    to a second), so that SIGTERM ends the service within pipeline.shutdown_timeout_s."""
    args = build_parser().parse_args(argv)
    setup_logging("debug" if args.verbose else args.log_level)
    code = _run(args)
    if exit_at_once and args.exit_at_once:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def entry() -> typing.NoReturn:
    """The `tofd` console script and `python -m tofd`."""
    sys.exit(main(exit_at_once=True))


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        kind = "config error: " if type(exc).__name__ == "ConfigError" else ""
        print(f"tofd {args.command}: {kind}{exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tofd {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 (an unexpected failure: one line, the traceback only with -v)
        logging.getLogger("tofd").debug("unexpected error", exc_info=True)
        print(f"tofd {args.command}: error: {type(exc).__name__}: {exc} (run with -v for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    entry()
