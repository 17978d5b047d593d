"""Rewrite a recording in the current format (e.g. one of format 1, which Foxglove and Rerun cannot show).

Every frame that replays from IN is written to OUT bit for bit, with IN's config; frames IN cannot replay
(damage, duplicates) are left out and counted. OUT appears only when complete (written beside it, then renamed).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="recording to read (.mcap, any format tofd replays)")
    parser.add_argument("out", type=Path, help="recording to write (.mcap; replaced if it exists)")


def main(args: argparse.Namespace) -> int:
    from tofd.drivers.recording.format import FORMAT_VERSION
    from tofd.drivers.recording.replay import ReplaySource
    from tofd.drivers.recording.writer import RecordingWriter
    from tofd.drivers.source import DriverError
    from tofd.errors import UsageError, input_error
    from tofd.outputs import check_output_file

    check_output_file(args.out, "OUT")
    try:
        source = ReplaySource(args.file)
    except (DriverError, OSError, ValueError) as exc:
        raise input_error(args.file, exc) from None
    info = source.info
    if info is None:
        raise UsageError(source.header_problem)
    tmp = args.out.with_name(f".{args.out.name}.{os.getpid()}.tmp")
    try:
        with source, RecordingWriter(tmp, config=info.config, fsync_interval_s=None) as writer:
            for frame in source:
                writer.write(frame)
        os.replace(tmp, args.out)
    finally:
        tmp.unlink(missing_ok=True)
    left_out = source.take_rejected_frames()
    print(f"tofd convert: wrote {args.out}: {writer.frames_written} frames "
          f"(format {info.format_version} -> {FORMAT_VERSION})"
          + (f", {left_out} left out (see the log)" if left_out else "")
          + ("" if source.stopped_reason == "end" else f"; {args.file} is {source.stopped_reason}: "
                                                     f"{source.stop_detail}"), file=sys.stderr)
    return 0
