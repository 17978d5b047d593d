"""Import a ROS bag (ROS 1 .bag; ROS 2 directory, .db3 or .mcap) as a tofd recording that `tofd replay` takes.

Each header stamp with a range image, an amplitude image and a CameraInfo becomes one frame; the intrinsics come
from the CameraInfo, so any image size works. Defaults are the topics of the SwissRanger ROS driver
(swissranger_camera, node SwissRanger): /SwissRanger/distance/image_raw16 (mono16 device units),
/SwissRanger/intensity/image_raw16 and /SwissRanger/camera_info. Range images: 32FC1 in metres, or 16UC1/mono16
in device units (--range-unit device: raw / 65535 x c / (2 f_mod), 0xFFFF = no return) or millimetres
(--range-unit mm, REP 118: 0 = no return); radial range or z-depth along the optical axis (--depth z, converted
to radial range with the CameraInfo's rays). The recording is written to a temporary file and renamed to OUT
only when every frame is in; a bad bag is one line and exit status 2. `tofd replay BAG` imports on the fly.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from tofd import arguments

if TYPE_CHECKING:
    from drivers.rosbag import RangeOptions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="ROS 1 .bag file, or ROS 2 bag directory, .db3 or .mcap file")
    parser.add_argument("out", type=Path, help="tofd recording to write (.mcap; replaced if it exists)")
    arguments.add_bag_arguments(parser)


def convert(bag: Path, out: Path, options: RangeOptions, command: str = "import") -> str:
    """Write the frames of `bag` to the recording `out` (renamed into place when complete) with a progress bar;
    returns what was written, e.g. "12 frames of 176x144". UsageError names a bad bag."""
    from drivers.recording.writer import RecordingWriter
    from drivers.bags import open_bag
    from drivers.rosbag import BagError
    from tofd.errors import UsageError
    from tofd.outputs import AtomicFile
    from tofd.progress import Progress

    try:
        source = open_bag(bag, options)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    provenance = {"import": {"bag": str(bag), **dataclasses.asdict(options), "source": source.settings}}
    progress = Progress(command, source.range_messages)
    # the writer opens the temp file by name; AtomicFile renames it to `out` only when every frame is in
    with source, AtomicFile(out, "wb") as target:
        try:
            with RecordingWriter(target.tmp_path, config=provenance, fsync_interval_s=None) as writer:
                for frame in source:
                    writer.write(frame)
                    progress.update(writer.frames_written)
        except BagError as exc:
            raise UsageError(str(exc)) from None
        finally:
            progress.done()
        unpaired = _unpaired(source.counters)
        if source.intrinsics is None:
            why = f"; {source.damage}" if source.damage else ""
            raise UsageError(f"{bag}: no header stamp has a range image, an amplitude image and a camera_info "
                             f"({unpaired or 'its topics are empty'}{why}); nothing written")
    size = f"{source.intrinsics.width}x{source.intrinsics.height}"
    damage = f"; damaged, the rest unread: {source.damage}" if source.damage else ""
    return f"{writer.frames_written} frames of {size}" + (f"; skipped {unpaired}" if unpaired else "") + damage


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.outputs import check_output_file

    check_output_file(args.out, "OUT")
    if args.out.resolve() == args.bag.resolve():
        raise UsageError(f"OUT {args.out}: is the bag itself")
    done = convert(args.bag, args.out, arguments.bag_options(args))
    print(f"tofd import: wrote {args.out}: {done} from {args.bag}", file=sys.stderr)
    return 0


def _unpaired(counters: dict[str, int]) -> str:
    """The messages left without the others of their stamp, e.g. "3 range, 1 camera_info messages unpaired"."""
    parts = [f"{n} {key.removeprefix('unpaired_')}" for key, n in sorted(counters.items())
             if key.startswith("unpaired_") and n]
    return f"{', '.join(parts)} messages unpaired" if parts else ""
