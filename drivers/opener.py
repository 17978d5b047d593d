"""What an input file is, told by its content (magic bytes, or a ROS 2 bag directory's metadata.yaml) rather than
its name, and the FrameSource that reads it: the one table `tofd replay`, `tofd import` and `tofd batch` consult.

Each InputFormat says how it is read: "recording" (tofd's own MCAP: tofd.drivers.recording.replay), "bag" (imported to a
tofd recording first: bags.driver_bag) or "source" (a FrameSource reading the file directly, made by `open`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from tofd.drivers.source import FrameSource

SNIFF_BYTES = 64
MCAP_MAGIC = b"\x89MCAP0\r\n"
MATROSKA_MAGIC = b"\x1a\x45\xdf\xa3"
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"
ROSBAG2_METADATA = "metadata.yaml"
TOFD_MCAP_PROFILE = "tofd"


@dataclass(frozen=True, slots=True)
class InputFormat:
    """A kind of input file: its name, what it is (for messages), how tofd reads it, and how to recognise it from
    the file's path and first SNIFF_BYTES bytes (empty for a directory)."""

    name: str
    description: str
    read_as: Literal["recording", "bag", "source"]
    matches: Callable[[Path, bytes], bool]
    open: Callable[[Path], FrameSource] | None = None  # the FrameSource reading a path directly: every "source"
    # format; ROS bags too (their drivers' topics, no options), for `tofd batch`


def _mcap_profile(path: Path) -> str | None:
    """The profile of an MCAP file's header record (None when it does not parse)."""
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as f:
            header = next(StreamReader(f, skip_magic=False).records)
    except Exception:  # noqa: BLE001 (a damaged header: whoever reads the file says what is wrong)
        return None
    return getattr(header, "profile", None)


def _is_tofd_recording(path: Path, head: bytes) -> bool:
    return head.startswith(MCAP_MAGIC) and _mcap_profile(path) in (TOFD_MCAP_PROFILE, None)


def _is_bag(path: Path, head: bytes) -> bool:
    if path.is_dir():
        return (path / ROSBAG2_METADATA).is_file()
    return (head.startswith((ROSBAG1_MAGIC, SQLITE_MAGIC))
            or (head.startswith(MCAP_MAGIC) and _mcap_profile(path) not in (TOFD_MCAP_PROFILE, None)))


def _bag_of(kind: str) -> Callable[[Path, bytes], bool]:
    """Whether a file is a ROS bag whose topics are those of a vendor SDK's recording `kind` (bags.opener)."""

    def matches(path: Path, head: bytes) -> bool:
        from tofd.drivers.bags.opener import bag_kind
        from tofd.drivers.source import DriverError

        if not _is_bag(path, head):
            return False
        try:
            return bag_kind(path) == kind
        except DriverError:  # unreadable: the plain ROS bag format says why
            return False

    return matches


def _open_bag(path: Path) -> FrameSource:
    from tofd.drivers.bags.opener import open_bag

    return open_bag(path)


def _open_k4a(path: Path) -> FrameSource:
    from tofd.drivers.k4a.mkv import K4aRecordingSource

    return K4aRecordingSource(path)


FORMATS: tuple[InputFormat, ...] = (
    InputFormat("tofd", "tofd recording (MCAP, profile tofd)", "recording", _is_tofd_recording),
    InputFormat("realsense", "RealSense SDK recording (librealsense >= 2.57 ROS 2 .db3, <= 2.56 ROS 1 .bag)", "bag",
                _bag_of("realsense"), _open_bag),
    InputFormat("orbbec", "Orbbec SDK v2 recording (ROS 1 .bag)", "bag", _bag_of("orbbec"), _open_bag),
    InputFormat("rosbag", "ROS bag (ROS 1 .bag; ROS 2 directory, .db3 or .mcap)", "bag", _is_bag, _open_bag),
    InputFormat("k4a", "Azure Kinect / Orbbec Femto recording (Matroska .mkv)", "source",
                lambda path, head: head.startswith(MATROSKA_MAGIC), _open_k4a),
)
"""The formats tofd reads, tried in order."""


def identify(path: str | Path) -> InputFormat:
    """The InputFormat of `path`; ValueError naming the file and why it is none of FORMATS (a FIFO, socket or
    device is refused before it is opened: reading one would block or never end)."""
    path = Path(path)
    if path.is_dir():
        head = b""
    elif path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a regular file (a FIFO, socket or device); tofd reads recordings from files")
    else:
        try:
            with open(path, "rb") as f:
                head = f.read(SNIFF_BYTES)
        except OSError as exc:
            raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    for fmt in FORMATS:
        if fmt.matches(path, head):
            return fmt
    what = "a directory without metadata.yaml" if path.is_dir() else (
        "an empty file" if not head else f"starts with {head[:16]!r}")
    raise ValueError(f"{path}: not a recording tofd reads ({what}); tofd reads: "
                     f"{'; '.join(f.description for f in FORMATS)}")


def open_source(path: str | Path) -> FrameSource:
    """The FrameSource reading `path` directly (a "source" format); ValueError for other formats."""
    fmt = identify(path)
    if fmt.open is None:
        raise ValueError(f"{path}: a {fmt.description} is not read directly")
    return fmt.open(Path(path))
