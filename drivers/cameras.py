"""The live cameras tofd attaches to, by kind: one interface over the SR3000 USB backend and the vendors' SDKs.

Each kind's backend lives in its own package (`tofd.drivers.<package>.camera`) and is imported only when that kind
is asked for, so a vendor SDK is needed only by the people who own that vendor's camera.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Protocol

from tofd.drivers.source import DriverError, FrameSource

SDK_KINDS = ("realsense", "orbbec", "k4a")
"""The cameras opened through their vendors' SDKs, each by the module tofd.drivers.<kind>.camera."""
CAMERA_KINDS = ("sr3000", *SDK_KINDS)
"""The camera kinds `tofd run --camera` and `[camera] kind` take; sr3000 is the SR3000-style USB camera
(tofd.drivers.usb.camera, opened by tofd.service.camera with the registers of [camera])."""
EXTRAS = {"realsense": "realsense", "orbbec": "orbbec", "k4a": "k4a"}
"""The pip extra that installs each SDK kind's SDK (the one place that names them)."""


@dataclass(frozen=True, slots=True)
class StreamMode:
    """The stream a camera is asked for; None leaves the choice to the device's default."""

    width: int | None = None  # depth image columns
    height: int | None = None  # depth image rows
    fps: int | None = None  # frames per second
    depth_mode: str | None = None  # the vendor's name of a depth mode, e.g. Azure Kinect "NFOV_UNBINNED"

    def describe(self) -> str:
        """E.g. "640x576 @ 30 fps, NFOV_UNBINNED" ("the device's default" when nothing is asked for)."""
        parts = [f"{self.width or '?'}x{self.height or '?'}" if self.width or self.height else "",
                 f"{self.fps} fps" if self.fps else "", self.depth_mode or ""]
        return ", ".join(p for p in parts if p) or "the device's default"


@dataclass(frozen=True, slots=True)
class CameraRequest:
    """Which camera to open and how: what `[camera]` in the config and `tofd run --camera` say."""

    kind: str
    serial: str = ""  # the vendor's serial number; "" = the first camera of this kind found
    mode: StreamMode = field(default_factory=StreamMode)
    playback: Path | None = None  # a recording handed to the vendor SDK as its device, played in real time
    settings: Mapping[str, float] = field(default_factory=dict)  # vendor settings by name, e.g. exposure_us
    read_timeout_s: float = 0.5  # seconds: one wait for a frame (then retried)
    stall_report_s: float = 2.0  # seconds without a frame before a stall is reported
    reconnect_initial_s: float = 0.1  # seconds: first wait before reopening a vanished camera
    reconnect_max_s: float = 5.0  # seconds: the wait doubles after each failed attempt up to this

    def __post_init__(self) -> None:
        if self.kind not in CAMERA_KINDS:
            raise ValueError(f"camera kind: {self.kind!r} is not one of {', '.join(CAMERA_KINDS)}")
        object.__setattr__(self, "settings", MappingProxyType({str(k): float(v) for k, v in self.settings.items()}))


@dataclass(frozen=True, slots=True)
class CameraListing:
    """One attached camera as `tofd devices` lists it."""

    kind: str
    model: str
    serial: str
    firmware: str = ""
    detail: str = ""  # e.g. the USB port, or why the camera cannot be queried


class SdkMissing(DriverError):
    """The vendor SDK a camera kind needs is not installed (or cannot load); says which extra installs it (exit 2,
    as for any command whose extra is missing)."""

    exit_status = 2

    def __init__(self, kind: str, detail: str = "") -> None:
        self.kind = kind
        self.extra = EXTRAS[kind]
        why = f" ({detail})" if detail else ""
        super().__init__(f"the {kind} camera needs its SDK{why}: pip install 'tofd[{self.extra}]'")


class PlaybackUnreadable(DriverError):
    """A --playback file the vendor's SDK cannot play (not its recording, or damaged): a data error, exit 2."""

    exit_status = 2


class CameraBackend(Protocol):
    """What each kind's backend module offers as its module attribute BACKEND."""

    kind: str

    def list_cameras(self) -> list[CameraListing]:
        """The attached cameras of this kind (empty when none is attached)."""
        ...

    def open(self, request: CameraRequest) -> FrameSource:
        """The camera (or with request.playback the recording) as a stream of Frames; DriverError if it can't."""
        ...


def backend(kind: str) -> CameraBackend:
    """The backend of SDK camera `kind`, its SDK imported now; SdkMissing when the SDK is not installed."""
    if kind not in SDK_KINDS:
        raise ValueError(f"camera kind: {kind!r} is not one of {', '.join(SDK_KINDS)}")
    try:
        module = importlib.import_module(f"tofd.drivers.{kind}.camera")
    except ImportError as exc:
        raise SdkMissing(kind, str(exc)) from exc
    found: CameraBackend = module.BACKEND
    return found
