"""The `tofd` command: one subcommand per module in tofd/commands/ (each has add_arguments and main)."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

import tofd.commands
from tofd.config import ConfigError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tofd", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in sorted(m.name for m in pkgutil.iter_modules(tofd.commands.__path__)):
        module = importlib.import_module(f"tofd.commands.{name}")
        summary = (module.__doc__ or "").strip().splitlines()[0]
        p = sub.add_parser(name, help=summary, description=module.__doc__)
        module.add_arguments(p)
        p.set_defaults(func=module.main)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ConfigError as exc:
        print(f"tofd: config error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
