"""What an input file is, told by its content (magic bytes, or a ROS 2 bag directory's metadata.yaml; a bag's topics
tell the vendor recordings from camera drivers' bags) rather than its name, and the FrameSource that reads it: the
one place that tells input kinds apart, for `tofd replay`, `import`, `info`, `export` and `batch`.

Each InputFormat says how it is read: "recording" (tofd's own MCAP: tofd.drivers.recording.replay), "bag" (a ROS
bag: tofd.drivers.bags; `tofd replay` imports it to a tofd recording first) or "source" (a FrameSource reading the
file directly: an Azure Kinect / Femto .mkv). `open_input` returns the format and the open source together: a bag
is opened once, to classify it and to read it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from mcap.writer import MCAP0_MAGIC

from tofd.drivers.bags.scan import ROS1_MAGIC, SQLITE_MAGIC
from tofd.drivers.k4a.mkv import MATROSKA_MAGIC
from tofd.drivers.source import DriverError, FrameSource

if TYPE_CHECKING:
    from tofd.drivers.bags.driver_bag import RangeOptions
    from tofd.drivers.bags.scan import BagReader

SNIFF_BYTES = 64
ROSBAG2_METADATA = "metadata.yaml"
TOFD_MCAP_PROFILE = "tofd"


@dataclass(frozen=True, slots=True)
class InputFormat:
    """A kind of input file: its name, what it is (for messages) and how tofd reads it."""

    name: str
    description: str
    read_as: Literal["recording", "bag", "source"]


TOFD = InputFormat("tofd", "tofd recording (MCAP, profile tofd)", "recording")
REALSENSE = InputFormat("realsense", "RealSense SDK recording (librealsense >= 2.57 ROS 2 .db3, <= 2.56 ROS 1 .bag)",
                        "bag")
ORBBEC = InputFormat("orbbec", "Orbbec SDK v2 recording (ROS 1 .bag)", "bag")
ROSBAG = InputFormat("rosbag", "ROS bag (ROS 1 .bag; ROS 2 directory, .db3 or .mcap)", "bag")
K4A = InputFormat("k4a", "Azure Kinect / Orbbec Femto recording (Matroska .mkv)", "source")
FORMATS: tuple[InputFormat, ...] = (TOFD, REALSENSE, ORBBEC, ROSBAG, K4A)
"""The formats tofd reads."""
_BAG_FORMATS = {"realsense": REALSENSE, "orbbec": ORBBEC, "driver": ROSBAG}  # bags.opener.bag_kind -> format


def _mcap_profile(path: Path) -> str | None:
    """The profile of an MCAP file's header record (None when it does not parse)."""
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as f:
            header = next(StreamReader(f, skip_magic=False).records)
    except Exception:  # noqa: BLE001 (a damaged header: whoever reads the file says what is wrong)
        return None
    return getattr(header, "profile", None)


def _head(path: Path) -> bytes:
    """The first SNIFF_BYTES bytes of a file (empty for a directory); ValueError naming an unreadable one."""
    if path.is_dir():
        return b""
    try:
        with open(path, "rb") as f:
            return f.read(SNIFF_BYTES)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None


def _recognise(path: Path) -> tuple[InputFormat, BagReader | None]:
    """The format of `path` and, for a bag, the bag open (None when it cannot be read: opening it again says
    why); ValueError naming the file and why it is none of FORMATS (a FIFO, socket or device is refused before it
    is opened: reading one would block or never end)."""
    if path.exists() and not path.is_file() and not path.is_dir():
        raise ValueError(f"{path}: not a regular file (a FIFO, socket or device); tofd reads recordings from files")
    head = _head(path)
    mcap = head.startswith(MCAP0_MAGIC)
    if mcap and _mcap_profile(path) in (TOFD_MCAP_PROFILE, None):
        return TOFD, None
    if head.startswith(MATROSKA_MAGIC):
        return K4A, None
    if (path / ROSBAG2_METADATA).is_file() if path.is_dir() else (mcap or head.startswith((ROS1_MAGIC, SQLITE_MAGIC))):
        from tofd.drivers.bags.opener import bag_kind
        from tofd.drivers.bags.scan import BagReader

        try:
            bag = BagReader(path)
        except DriverError:
            return ROSBAG, None
        try:
            return _BAG_FORMATS[bag_kind(bag)], bag
        except BaseException:
            bag.close()
            raise
    what = "a directory without metadata.yaml" if path.is_dir() else (
        "an empty file" if not head else f"starts with {head[:16]!r}")
    raise ValueError(f"{path}: not a recording tofd reads ({what}); tofd reads: "
                     f"{'; '.join(f.description for f in FORMATS)}")


def identify(path: str | Path) -> InputFormat:
    """The InputFormat of `path`; ValueError naming the file and why it is none of FORMATS."""
    fmt, bag = _recognise(Path(path))
    if bag is not None:
        bag.close()
    return fmt


def open_input(path: str | Path, bag_options: RangeOptions | None = None) -> tuple[InputFormat, FrameSource]:
    """The InputFormat of `path` and a lossless FrameSource reading it from its first frame (`bag_options`: a ROS
    bag's topics and range encoding). ValueError when it is none of FORMATS; DriverError (or OSError) when it
    cannot be read."""
    path = Path(path)
    fmt, bag = _recognise(path)
    if fmt.read_as == "bag":
        from tofd.drivers.bags.opener import open_bag

        return fmt, open_bag(path, bag_options, bag)
    if fmt.read_as == "source":
        from tofd.drivers.k4a.mkv import K4aRecordingSource

        return fmt, K4aRecordingSource(path)
    from tofd.drivers.recording.replay import ReplaySource

    return fmt, ReplaySource(path)
