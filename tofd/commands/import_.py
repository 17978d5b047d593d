"""Import a ROS bag (ROS 1 .bag; ROS 2 directory, .db3 or .mcap) as a tofd recording that `tofd replay` takes.

Each header stamp with a range image, an amplitude image and a CameraInfo becomes one frame; the intrinsics come
from the CameraInfo, so any image size works. Defaults are the topics of the SwissRanger ROS driver
(swissranger_camera, node SwissRanger): /SwissRanger/distance/image_raw16 (mono16 device units),
/SwissRanger/intensity/image_raw16 and /SwissRanger/camera_info. Range images: 32FC1 in metres, or 16UC1/mono16
in device units (--range-unit device: raw / 65535 x c / (2 f_mod), 0xFFFF = no return) or millimetres
(--range-unit mm, REP 118: 0 = no return); radial range or z-depth along the optical axis (--depth z, converted
to radial range with the CameraInfo's rays). The recording is written to a temporary file and renamed to OUT
only when every frame is in; a bad bag is one line and exit status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from tofd import arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from drivers.rosbag import DEPTH_CONVENTIONS, RANGE_UNITS, RangeOptions

    d = RangeOptions()
    parser.add_argument("bag", type=Path, help="ROS 1 .bag file, or ROS 2 bag directory, .db3 or .mcap file")
    parser.add_argument("out", type=Path, help="tofd recording to write (.mcap; replaced if it exists)")
    parser.add_argument("--range-topic", default=d.range_topic,
                        help="sensor_msgs/Image of range (default: %(default)s)")
    parser.add_argument("--amplitude-topic", default=d.amplitude_topic,
                        help="sensor_msgs/Image of amplitude/intensity (default: %(default)s)")
    parser.add_argument("--camera-info-topic", default=d.camera_info_topic,
                        help="sensor_msgs/CameraInfo with the intrinsics (default: %(default)s)")
    parser.add_argument("--range-unit", choices=RANGE_UNITS, default=d.range_unit,
                        help="unit of 16-bit range images: SwissRanger device units or millimetres; 32FC1 is "
                             "always metres (default: %(default)s)")
    parser.add_argument("--depth", choices=DEPTH_CONVENTIONS, default=d.depth,
                        help="range along each pixel's ray (radial) or along the optical axis (z) "
                             "(default: %(default)s)")
    parser.add_argument("--mod-freq-mhz", type=arguments.positive_float, default=d.mod_freq_mhz,
                        help="modulation frequency for --range-unit device, MHz (default: %(default)s)")


def main(args: argparse.Namespace) -> int:
    from drivers.recording.writer import RecordingWriter
    from drivers.rosbag import BagError, RangeOptions, RosbagSource
    from tofd.errors import UsageError
    from tofd.outputs import AtomicFile, check_output_file
    from tofd.progress import Progress

    options = RangeOptions(args.range_topic, args.amplitude_topic, args.camera_info_topic, args.range_unit,
                           args.depth, args.mod_freq_mhz)
    check_output_file(args.out, "OUT")
    if args.out.resolve() == args.bag.resolve():
        raise UsageError(f"OUT {args.out}: is the bag itself")
    try:
        source = RosbagSource(args.bag, options)
    except BagError as exc:
        raise UsageError(str(exc)) from None
    provenance = {"import": {"bag": str(args.bag), **dataclasses.asdict(options)}}
    progress = Progress("import", source.range_messages)
    # the writer opens the temp file by name; AtomicFile renames it to OUT only when every frame is in
    with source, AtomicFile(args.out, "wb") as target:
        try:
            with RecordingWriter(target.tmp_path, config=provenance) as writer:
                for frame in source:
                    writer.write(frame)
                    progress.update(writer.frames_written)
        except BagError as exc:
            raise UsageError(str(exc)) from None
        finally:
            progress.done()
        if writer.frames_written == 0:
            raise UsageError(f"{args.bag}: no header stamp has a range image, an amplitude image and a camera_info "
                             f"({_unpaired(source.counters) or 'its topics are empty'}); nothing written")
    first = source.intrinsics
    print(f"tofd import: wrote {args.out}: {writer.frames_written} frames of {first.width}x{first.height} from "
          f"{args.bag}" + (f"; skipped {_unpaired(source.counters)}" if _unpaired(source.counters) else ""),
          file=sys.stderr)
    return 0


def _unpaired(counters: dict[str, int]) -> str:
    """The messages left without the others of their stamp, e.g. "3 range, 1 camera_info messages unpaired"."""
    parts = [f"{n} {key.removeprefix('unpaired_')}" for key, n in sorted(counters.items())
             if key.startswith("unpaired_") and n]
    return f"{', '.join(parts)} messages unpaired" if parts else ""
