"""argparse value types shared by the subcommands: each rejects a bad value with one line naming what it expects."""

from __future__ import annotations

import argparse
import math

from tofd.config import check_serial


def positive_int(text: str) -> int:
    """An integer >= 1 (e.g. --frames)."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
    return value


def frame_counter(text: str) -> int:
    """A device frame counter, >= 0 (e.g. --seek)."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a frame counter >= 0, got {text}")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (e.g. --speed, --seconds)."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return value


def serial(text: str) -> str:
    """A camera serial: 8 hex digits (the config's rule, tofd.config.check_serial)."""
    try:
        return check_serial(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("serial: ")) from None
