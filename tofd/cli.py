"""The `tofd` command: one subcommand per module in tofd/commands/ (each has add_arguments and main); a trailing
underscore of a module name (import_) keeps a Python keyword out of the module name and out of the command name."""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
import logging
import os
import pkgutil
import sys
import typing
from collections.abc import Collection
from pathlib import Path

import tofd
import tofd.commands
from tofd.errors import ConfigError, TofdError
from tofd.extras import install_hint, missing_extra
from tofd.logs import LEVELS, setup_logging

DESCRIPTION = """\
tofd: scale-invariant range features (Haker et al. 2008) and nose detection for SR3000-style time-of-flight
cameras. It runs as a live camera daemon (Rerun viewer, /healthz, /metrics), records and replays MCAP
recordings, and trains and evaluates the nose detector.

Exit status: 0 success, 1 runtime failure (camera, viewer, pipeline), 2 usage or data error, 130 interrupted
(Ctrl-C; 143 when a replay is stopped by SIGTERM; `tofd run`, a service, exits 0 on either).
Signals: SIGTERM, SIGINT, SIGHUP and SIGQUIT stop (a running service drains, writes its summary and exits 0;
while tofd loads: `interrupted`, 130); SIGUSR1 logs a status line."""

EPILOG = "Start with `tofd run --emulate --rerun web` (no camera needed), or `tofd COMMAND --help`."


class _Parser(argparse.ArgumentParser):
    """An argument mistake is one line on stderr (pointing to --help) and exit status 2."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _command_modules() -> dict[str, str]:
    """Command name -> module name in tofd.commands, in command-name order."""
    names = sorted(m.name for m in pkgutil.iter_modules(tofd.commands.__path__))
    return {name.removesuffix("_"): name for name in names}


def _docstring(module: str) -> str:
    """The module's docstring, read from its source without importing it (imports of some commands take seconds)."""
    spec = importlib.util.find_spec(f"tofd.commands.{module}")
    assert spec is not None and spec.origin is not None
    return ast.get_docstring(ast.parse(Path(spec.origin).read_text(encoding="utf-8"))) or ""


def build_parser(full: Collection[str] | None = None, commands: dict[str, str] | None = None
                 ) -> argparse.ArgumentParser:
    """The parser of `commands` (_command_modules() when None); only the commands in `full` (all when None) import
    their module and get their arguments."""
    parser = _Parser(prog="tofd", description=DESCRIPTION, epilog=EPILOG,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"tofd {tofd.__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages (same as --log-level debug)")
    parser.add_argument("--log-level", choices=LEVELS, default="info", help="lowest level logged (default info)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_Parser)
    for command, module_name in (commands or _command_modules()).items():
        doc = _docstring(module_name)
        p = sub.add_parser(command, help=doc.splitlines()[0] if doc else "", description=doc,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        if full is None or command in full:
            module = importlib.import_module(f"tofd.commands.{module_name}")
            module.add_arguments(p)
            p.set_defaults(func=module.main, exit_at_once=getattr(module, "EXIT_AT_ONCE", False))
    return parser


def _named_command(argv: list[str], commands: Collection[str]) -> set[str]:
    """The command named on the command line (its first word that is one of `commands`), or none."""
    return next(({word} for word in argv if word in commands), set())


def main(argv: list[str] | None = None, *, exit_at_once: bool = False) -> int:
    """Run one `tofd` command; its exit status. With `exit_at_once`, a command whose module sets EXIT_AT_ONCE
    (the service commands: their outputs are written and their children gone when they return) ends the
    process right away, without the interpreter's teardown of its modules (the Rerun SDK, numpy, ... take up
    to a second), so that SIGTERM ends the service within pipeline.shutdown_timeout_s."""
    argv = sys.argv[1:] if argv is None else argv
    commands = _command_modules()
    named = _named_command(argv, commands)
    try:
        parser = build_parser(named, commands)
        args = parser.parse_args(argv)
        setup_logging("debug" if args.verbose else args.log_level)
    except ImportError as exc:  # the command's module needs an extra that is not installed
        command = next(iter(named), "")
        extra = missing_extra(exc, command)
        if extra is None:
            raise
        print(f"tofd {command}: {install_hint(extra)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # a stop signal while the command's modules load
        print(f"tofd: interrupted{_signal_name(exc)}", file=sys.stderr)
        return 130
    except RuntimeError as exc:
        interrupt = stop_signal_behind(exc)
        if interrupt is None:
            raise
        print(f"tofd: interrupted{_signal_name(interrupt)}", file=sys.stderr)
        return 130
    code = _run(args)
    if exit_at_once and getattr(args, "exit_at_once", False):
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def entry() -> typing.NoReturn:
    """The `tofd` console script and `python -m tofd` (stop signals while it loads: tofd.service.signals)."""
    from tofd.service.signals import interrupt_while_loading  # stdlib only: cheap to load first

    interrupt_while_loading()
    sys.exit(main(exit_at_once=True))


def stop_signal_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The stop signal an exception was raised from, if any: Python 3.11 re-raises one that arrives while a module
    defines a class (in a descriptor's __set_name__, e.g. a dataclass field) as a RuntimeError from it."""
    cause: BaseException | None = exc
    while cause is not None and not isinstance(cause, KeyboardInterrupt):
        cause = cause.__cause__
    return cause


def _signal_name(exc: KeyboardInterrupt) -> str:
    """" (SIGHUP)" for the signal an Interrupted names, "" for a plain KeyboardInterrupt."""
    from tofd.service.signals import Interrupted

    return f" ({exc})" if isinstance(exc, Interrupted) else ""


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args) or 0)
    except ConfigError as exc:
        print(f"tofd {args.command}: config error: {exc}", file=sys.stderr)
        return exc.exit_status
    except TofdError as exc:  # usage, config and data mistakes exit 2, runtime failures 1
        print(f"tofd {args.command}: {exc}", file=sys.stderr)
        return exc.exit_status
    except OSError as exc:  # a file, socket or device the command could not use: a runtime failure
        logging.getLogger("tofd").debug("I/O error", exc_info=True)
        print(f"tofd {args.command}: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"tofd {args.command}: interrupted{_signal_name(exc)}", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 (an unexpected failure: one line, the traceback only with -v)
        interrupt = stop_signal_behind(exc)
        if interrupt is not None:
            print(f"tofd {args.command}: interrupted{_signal_name(interrupt)}", file=sys.stderr)
            return 130
        extra = missing_extra(exc, args.command) if isinstance(exc, ImportError) else None
        if extra is not None:  # a module of an extra that is not installed, imported as the command ran
            print(f"tofd {args.command}: {install_hint(extra)}", file=sys.stderr)
            return 2
        logging.getLogger("tofd").debug("unexpected error", exc_info=True)
        print(f"tofd {args.command}: error: {type(exc).__name__}: {exc} (run with -v for the traceback)",
              file=sys.stderr)
        return 1


if __name__ == "__main__":
    entry()
