"""Import a ROS bag (ROS 1 .bag; ROS 2 directory, .db3 or .mcap) or an Azure Kinect / Orbbec Femto .mkv as a tofd
recording that `tofd replay` takes (inputs are recognised by content: tofd.drivers.opener).

A RealSense SDK recording (librealsense's ROS 2 .db3 or legacy ROS 1 .bag) or an Orbbec SDK v2 .bag is read
as its SDK wrote it (depth + infrared by frame number, units, lens and device from the file). In a camera
driver's bag each header stamp with a range image, an amplitude image and a CameraInfo becomes one frame, on the
topics of the driver the bag's topics show (swissranger_camera, orbbec_camera, azure_kinect_ros_driver,
realsense2_camera, royale; bags.driver_layouts) or those named by the options. Range images: 32FC1 in metres,
or 16UC1/mono16 in device units (--range-unit device: raw / 65535 x c / (2 f_mod), 0xFFFF = no return) or
millimetres (--range-unit mm, REP 118: 0 = no return); radial range or z-depth along the optical axis (--depth z,
converted to radial range with the CameraInfo's undistorted rays). A damaged bag gives the frames before the
damage. The recording is written to a temporary file and renamed to OUT
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
    from tofd.drivers.bags.driver_bag import RangeOptions
    from tofd.drivers.source import FrameSource, Rejected


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="ROS 1 .bag file, ROS 2 bag directory, .db3 or .mcap file, or Azure "
                                               "Kinect / Orbbec Femto .mkv")
    parser.add_argument("out", type=Path, help="tofd recording to write (.mcap; replaced if it exists)")
    arguments.add_bag_arguments(parser)


def convert(bag: Path, out: Path, options: RangeOptions, command: str = "import",
            rejected: list[Rejected] | None = None) -> str:
    """Write the frames of `bag` to the recording `out` (renamed into place when complete) with a progress bar;
    returns what was written, e.g. "12 frames of 176x144". The frames the source rejected (a damaged tail) are
    added to `rejected`. UsageError names a bad bag."""
    from tofd.drivers.bags.driver_bag import BagError, RangeOptions
    from tofd.drivers.bags.opener import open_bag
    from tofd.drivers.opener import identify, open_source
    from tofd.drivers.recording.writer import RecordingWriter
    from tofd.drivers.source import DriverError
    from tofd.errors import UsageError
    from tofd.outputs import AtomicFile
    from tofd.progress import Progress

    try:
        fmt = identify(bag)
        if fmt.read_as == "recording":
            raise UsageError(f"{bag} is already a tofd recording: replay it as it is")
        source: FrameSource = open_bag(bag, options) if fmt.read_as == "bag" else open_source(bag)
    except (BagError, DriverError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    if fmt.read_as != "bag" and options != RangeOptions():
        raise UsageError(f"{bag} is a {fmt.description}: the ROS bag options are for ROS bags")
    provenance = {"import": {"bag": str(bag), **dataclasses.asdict(options),
                             "source": getattr(source, "settings", {})} if fmt.read_as == "bag"
                  else {"file": str(bag), "format": fmt.name}}
    progress = Progress(command, getattr(source, "range_messages", None))
    # the writer opens the temp file by name; AtomicFile renames it to `out` only when every frame is in
    with source, AtomicFile(out, "wb") as target:
        try:
            with RecordingWriter(target.tmp_path, config=provenance, fsync_interval_s=None) as writer:
                for frame in source:
                    writer.write(frame)
                    progress.update(writer.frames_written)
        except (BagError, DriverError) as exc:
            raise UsageError(str(exc)) from None
        finally:
            progress.done()
        unpaired = _unpaired(source.counters)
        intrinsics = getattr(source, "intrinsics", None)
        damage = getattr(source, "damage", None)
        if intrinsics is None or not writer.frames_written:
            why = f"; {damage}" if damage else ""
            raise UsageError(f"{bag}: no header stamp has a range image, an amplitude image and a camera_info "
                             f"({unpaired or 'its topics are empty'}{why}); nothing written" if fmt.read_as == "bag"
                             else f"{bag}: no frame could be read; nothing written")
    lost_frames = source.take_rejected()
    lost = sum(r.frames for r in lost_frames)
    if rejected is not None:
        rejected.extend(lost_frames)
    skipped = "; ".join(filter(None, [unpaired, f"{lost} frames lost or damaged (see the log)" if lost else ""]))
    size = f"{intrinsics.width}x{intrinsics.height}"
    damaged = f"; damaged, the rest unread: {damage}" if damage else ""
    return f"{writer.frames_written} frames of {size}" + (f"; skipped {skipped}" if skipped else "") + damaged


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
    """The messages left without the others of their stamp and those that did not decode, e.g. "3 range,
    1 camera_info messages unpaired; 1 garbled message skipped"."""
    parts = [f"{n} {key.removeprefix('unpaired_')}" for key, n in sorted(counters.items())
             if key.startswith("unpaired_") and n]
    garbled = counters.get("damaged_message", 0)
    return "; ".join(filter(None, [f"{', '.join(parts)} messages unpaired" if parts else "",
                                   f"{garbled} garbled message{'s' * (garbled != 1)} skipped" if garbled else ""]))
