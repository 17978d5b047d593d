"""Record frames from the camera (or the emulated one) to a crash-safe, self-describing MCAP file.

Stops after --frames or --seconds, or on Ctrl-C / SIGTERM, and then closes the file properly. Even if the
process is killed, every frame written up to that moment replays (`tofd replay OUT`). Progress goes to
stderr once a second; a summary with the camera's fault counters is printed at the end.
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

from tofd import arguments

if TYPE_CHECKING:
    from collections.abc import Callable

    from tofd.drivers.source import FrameSource

PROGRESS_INTERVAL_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", type=Path, help="recording to write (.mcap; overwritten if it exists)")
    parser.add_argument("--emulate", action="store_true", help="record the emulated camera (no hardware)")
    limit = parser.add_mutually_exclusive_group()
    limit.add_argument("--frames", type=arguments.positive_int, help="stop after this many frames")
    limit.add_argument("--seconds", type=arguments.positive_float, help="stop after this many seconds of recording")
    parser.add_argument("--config", type=Path, default=None, help="config file (default: config/tofd.toml)")
    arguments.add_camera_arguments(parser)


def _finish_on_signal(source: FrameSource) -> Callable[[int, bool], None]:
    """StopSignals' callback: say so on the first signal, close the source from a helper thread (its read
    may be blocked)."""

    def finish(signum: int, first: bool) -> None:
        if first:
            print(f"\n{signal.Signals(signum).name}: finishing the recording", file=sys.stderr)
        threading.Thread(target=source.close, daemon=True).start()

    return finish


def _status(frames: int, elapsed_s: float, nbytes: int, counters: dict[str, int]) -> str:
    faults = ", ".join(f"{k} {v}" for k, v in sorted(counters.items()) if v and k != "frames")
    fps = frames / elapsed_s if elapsed_s > 0 else 0.0
    return (f"{frames} frames, {elapsed_s:.1f} s, {nbytes / 1e6:.2f} MB, {fps:.1f} fps"
            + (f"; {faults}" if faults else ""))


def main(args: argparse.Namespace) -> int:
    from tofd.config import load_config
    from tofd.drivers.recording.writer import RecordingWriter
    from tofd.service.camera import open_camera
    from tofd.service.signals import StopSignals

    config = load_config(args.config)
    config = dataclasses.replace(config, camera=arguments.camera_config(config.camera, args))
    source = open_camera(config, args.emulate)
    tty = sys.stderr.isatty()
    frames = 0
    t_start = time.monotonic()
    try:
        with source, StopSignals(_finish_on_signal(source)) as stop, \
                RecordingWriter(args.out, config=dataclasses.asdict(config)) as writer:
            print(f"recording to {args.out} (Ctrl-C to stop)", file=sys.stderr)
            next_report = t_start + PROGRESS_INTERVAL_S
            for frame in source:
                writer.write(frame)
                frames += 1
                now = time.monotonic()
                if now >= next_report:
                    line = _status(frames, now - t_start, writer.bytes_written, source.counters)
                    print(f"\r{line}" if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
                    next_report = now + PROGRESS_INTERVAL_S
                if stop or (args.frames is not None and frames >= args.frames) or \
                        (args.seconds is not None and now - t_start >= args.seconds):
                    break
    except OSError as exc:
        print(f"\ntofd record: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    if tty:
        print(file=sys.stderr)
    summary = _status(frames, time.monotonic() - t_start, args.out.stat().st_size, source.counters)
    print(f"wrote {args.out}: {summary}" + _explain_device_drops(source.counters["device_dropped"]))
    return 0


def _explain_device_drops(dropped: int) -> str:
    if not dropped:
        return ""
    return (f" ({dropped} frames the camera produced were overwritten in its frame buffer before tofd read them: "
            "the host fell behind the camera, e.g. a busy CPU or a slow disk; the recording has counter gaps there)")
