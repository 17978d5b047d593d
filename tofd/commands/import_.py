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
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from tofd import arguments

if TYPE_CHECKING:
    pass


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="ROS 1 .bag file, ROS 2 bag directory, .db3 or .mcap file, or Azure "
                                               "Kinect / Orbbec Femto .mkv")
    parser.add_argument("out", type=Path, help="tofd recording to write (.mcap; replaced if it exists)")
    arguments.add_bag_arguments(parser)


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.inputs import convert, open_reader
    from tofd.outputs import check_output_file
    from tofd.progress import Progress

    check_output_file(args.out, "OUT")
    if args.out.resolve() == args.bag.resolve():
        raise UsageError(f"OUT {args.out}: is the bag itself")
    options = arguments.bag_options(args)
    fmt, source = open_reader(args.bag, options)
    if fmt.read_as == "recording":
        source.close()
        raise UsageError(f"{args.bag} is already a tofd recording: replay it as it is")
    done = convert(args.bag, fmt, source, options, args.out, lambda total: Progress("import", total))
    print(f"tofd import: wrote {args.out}: {done} from {args.bag}", file=sys.stderr)
    return 0
