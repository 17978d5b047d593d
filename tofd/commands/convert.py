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
    from tofd.drivers.recording.writer import RecordingWriter
    from tofd.inputs import open_recording
    from tofd.outputs import check_output_file

    check_output_file(args.out, "OUT")
    source, info = open_recording(args.file)
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
          + (f"; {args.file} is {source.report.reason}: {source.report.detail}" if source.report.stopped_early
             else ""), file=sys.stderr)
    return 0
