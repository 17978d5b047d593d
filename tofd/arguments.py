"""argparse value types shared by the subcommands: each rejects a bad value with one line naming what it expects."""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from tofd.config import check_serial

if TYPE_CHECKING:
    from tofd.drivers.bags.driver_bag import RangeOptions


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


def add_bag_arguments(parser: argparse.ArgumentParser) -> None:
    """How a ROS bag holds frames (tofd.drivers.bags.driver_bag.RangeOptions; defaults: the bag's driver's)."""
    from tofd.drivers.bags.driver_bag import (
        AMPLITUDE_ENCODINGS,
        DEPTH_CONVENTIONS,
        RANGE_ENCODINGS,
        RANGE_UNITS,
        RangeOptions,
    )
    from tofd.drivers.bags.driver_layouts import LAYOUTS

    d = RangeOptions()
    group = parser.add_argument_group(
        "ROS bags", "topics and range encoding of a ROS 1 or ROS 2 bag; by default those of the driver its topics "
        f"show ({', '.join(layout.driver for layout in LAYOUTS)})")
    group.add_argument("--range-topic", metavar="TOPIC",
                       help=f"sensor_msgs/Image or CompressedImage of range: {', '.join(RANGE_ENCODINGS)}")
    group.add_argument("--amplitude-topic", metavar="TOPIC",
                       help=f"sensor_msgs/Image or CompressedImage of amplitude/IR: {', '.join(AMPLITUDE_ENCODINGS)}")
    group.add_argument("--camera-info-topic", metavar="TOPIC",
                       help="sensor_msgs/CameraInfo with the intrinsics and lens model")
    group.add_argument("--range-unit", choices=RANGE_UNITS,
                       help="unit of 16-bit range images: SwissRanger device units or millimetres; 32FC1 is always "
                            "metres (default: the driver's)")
    group.add_argument("--depth", choices=DEPTH_CONVENTIONS,
                       help="range along each pixel's ray (radial) or along the optical axis (z) "
                            "(default: the driver's)")
    group.add_argument("--mod-freq-mhz", type=positive_float, default=d.mod_freq_mhz, metavar="MHZ",
                       help="modulation frequency for --range-unit device, MHz (default: %(default)s)")


def bag_options(args: argparse.Namespace) -> RangeOptions:
    """The RangeOptions of add_bag_arguments' options."""
    from tofd.drivers.bags.driver_bag import RangeOptions

    return RangeOptions(args.range_topic, args.amplitude_topic, args.camera_info_topic, args.range_unit, args.depth,
                        args.mod_freq_mhz)
