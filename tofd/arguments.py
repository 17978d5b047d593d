"""argparse value types shared by the subcommands: each rejects a bad value with one line naming what it expects."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

from tofd.config import CameraConfig, check_serial
from tofd.drivers.cameras import CAMERA_KINDS
from tofd.errors import UsageError

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
    """A camera serial number of any kind (the config's rule, tofd.config.check_serial; an SR3000's 8 hex digits
    are checked with the camera kind, when the config is complete)."""
    try:
        return check_serial(text, kind="any")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("serial: ")) from None


def add_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """--camera, --serial and --playback: which camera `run` and `record` attach to (overriding [camera])."""
    parser.add_argument("--camera", choices=CAMERA_KINDS, default=None, metavar="KIND",
                        help=f"camera kind: {', '.join(CAMERA_KINDS)} (overrides [camera] kind; default sr3000)")
    parser.add_argument("--serial", type=serial, default=None,
                        help="the camera's serial number (SR3000: 8 hex digits; overrides [camera] serial)")
    parser.add_argument("--playback", type=Path, default=None, metavar="FILE",
                        help="an SDK camera's recording, played by the vendor's SDK as its device in real time "
                             "(overrides [camera] playback)")


def camera_config(camera: CameraConfig, args: argparse.Namespace) -> CameraConfig:
    """[camera] with --camera, --serial and --playback applied, validated as a whole (UsageError names the
    option: e.g. an SR3000 serial that is not 8 hex digits)."""
    changes: dict[str, object] = {}
    if args.camera is not None:
        changes["kind"] = args.camera
    if args.serial is not None:
        changes["serial"] = args.serial
    if args.playback is not None:
        if not args.playback.is_file():
            raise UsageError(f"--playback: {args.playback} is not a file")
        changes["playback"] = str(args.playback)
    camera = dataclasses.replace(camera, **changes)  # type: ignore[arg-type]
    try:
        camera.validate()
    except ValueError as exc:
        key = str(exc).partition(":")[0]
        option = {"kind": "--camera", "serial": "--serial", "playback": "--playback"}.get(key)
        raise UsageError(f"{option or 'camera.' + key}:{str(exc).partition(':')[2]}") from None
    return camera


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
