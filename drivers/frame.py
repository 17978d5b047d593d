"""The typed frame that crosses every boundary from the drivers up to the viewer."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Literal

import numpy as np

from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.sr3000 import MOD_FREQS_MHZ, mod_freq_khz, range_unit_m

COUNTER_LIMIT = 1 << 32
"""Frame counters are 32-bit on the device: 0 <= counter < COUNTER_LIMIT."""
TIMESTAMP_LIMIT_US = 1 << 63
"""Device timestamps are non-negative int64 microseconds."""
PERIOD_FRAMES = 8
"""Frames whose device timestamps give a file source's frame period (SensorInfo.frame_period_s) before it
delivers the first one."""


@dataclass(frozen=True, slots=True)
class Registers:
    """Camera register settings a frame was taken with (SR3000 register map)."""

    int_time_code: int = 30  # INT_TIME 0x01: (code + 1) * 0.2 ms
    mod_freq_index: int = 3  # MOD_FREQ 0x02: index into MOD_FREQS_MHZ
    acq_mode: int = 0x05  # ACQ_MODE 0x03, opaque
    data_source: int = 0  # DATA_SOURCE 0x04: 0 scene, 1 test pattern
    amp_threshold: int = 0  # AMP_THR_LO/HI 0x05/0x06, opaque

    @property
    def integration_time_s(self) -> float:
        return (self.int_time_code + 1) * 0.2e-3

    @property
    def mod_freq_hz(self) -> float:
        return MOD_FREQS_MHZ[self.mod_freq_index] * 1e6

    @property
    def depth_unit_m(self) -> float:
        """Metres per raw distance unit of the range image (its 16 bits span the non-ambiguity range)."""
        return range_unit_m(mod_freq_khz(self.mod_freq_index))


DEFAULT_REGISTER_VALUES = Registers()
"""The camera's power-up settings: the one definition of the register defaults (protocol, emulator, UsbCamera
and tofd's [camera] config take theirs from here)."""


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """Identity of the source of a frame."""

    serial: str  # 8 upper-case hex digits for USB devices
    firmware: str = ""  # e.g. "1.0"
    backend: str = "usb"  # "usb", "emulated" or "replay"
    model: str = "SR3000"


AmplitudeKind = Literal["amplitude", "ir", "active_brightness"]
AMPLITUDE_KINDS: tuple[AmplitudeKind, ...] = ("amplitude", "ir", "active_brightness")
"""What a frame's amplitude plane is: the modulation amplitude of the returned light (SR3000, pmd), a plain
infrared image (Azure Kinect, RealSense, Orbbec) or a ToF active-brightness / gray-value image."""


@dataclass(frozen=True, slots=True)
class SensorInfo:
    """What a source other than the SR3000 knows about its signal and settings, read from its file.

    The SR3000 describes itself with Registers; other cameras have no such register map, so their frames carry
    this instead (and `Frame.registers` is None).
    """

    depth_unit_m: float  # metres per raw depth value in the file (1.0: the file holds float metres)
    amplitude: AmplitudeKind  # what the amplitude plane is
    invalid_value: int | None = 0  # raw depth value that means no return (None: the file has none)
    amplitude_full_scale: float | None = None  # largest raw amplitude (255 mono8, 65535 mono16; None: float)
    unambiguous_range_m: float | None = None  # None: unknown or not stated by the file
    frame_period_s: float | None = None  # median spacing of the device timestamps, seconds (None: < 2 frames)
    settings: Mapping[str, str] = field(default_factory=dict)  # the vendor's settings as the file names them

    def __post_init__(self) -> None:
        if self.amplitude not in AMPLITUDE_KINDS:
            raise ValueError(f"amplitude: {self.amplitude!r} is not one of {AMPLITUDE_KINDS}")
        if not (math.isfinite(self.depth_unit_m) and self.depth_unit_m > 0):
            raise ValueError(f"depth_unit_m: {self.depth_unit_m!r} is not a positive number of metres")
        if not isinstance(self.settings, Mapping):
            raise TypeError(f"settings: expected a mapping of names to values, got {type(self.settings).__name__}")
        object.__setattr__(self, "settings", MappingProxyType({str(k): str(v) for k, v in self.settings.items()}))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready fields (settings as a plain dict)."""
        return {f.name: dict(self.settings) if f.name == "settings" else getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> SensorInfo:
        """The SensorInfo of a to_dict() mapping (unknown keys are refused: TypeError)."""
        return cls(**data)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """Labelled nose tip of a frame, when the source knows it (emulator, labelled recordings)."""

    nose_px: tuple[float, float]  # (u, v) = (column, row) in pixels
    visible: bool = True
    nose_xyz_m: tuple[float, float, float] | None = None  # camera frame, metres


@dataclass(slots=True)
class Frame:
    """One TOF frame: radial range in metres (NaN invalid) and amplitude, with timing and provenance."""

    range_m: np.ndarray  # (H, W) float32, metres along each pixel's ray, NaN where invalid
    amplitude: np.ndarray  # (H, W) float32, sensor units
    frame_counter: int
    timestamp_us: int  # device clock, microseconds, end of exposure
    host_monotonic_s: float  # time.monotonic() when the host received the frame
    host_wall_s: float  # time.time() when the host received the frame
    intrinsics: Intrinsics = field(default_factory=Intrinsics)
    device: DeviceInfo = field(default_factory=lambda: DeviceInfo(serial="00000000"))
    registers: Registers | None = None  # the SR3000's register settings; None: the source has no such registers
    ground_truth: GroundTruth | None = None
    sensor: SensorInfo | None = None  # signal and settings of a non-SR3000 source, from its file


def frame_problem(frame: Frame, shape: tuple[int, int]) -> str | None:
    """Why `frame` cannot enter the pipeline, or None: planes float32 of `shape` (H, W) and of its own
    intrinsics' shape, counter in [0, 2**32), device timestamp in [0, 2**63) us, finite host times."""
    for name in ("range_m", "amplitude"):
        plane = getattr(frame, name)
        if not isinstance(plane, np.ndarray) or plane.dtype != np.float32 or plane.shape != shape:
            got = f"{getattr(plane, 'dtype', type(plane).__name__)} {getattr(plane, 'shape', '')}".strip()
            return f"{name} is {got}, expected float32 {shape}"
    if frame.intrinsics.shape != shape:
        return f"intrinsics are {frame.intrinsics.width}x{frame.intrinsics.height}, expected {shape[1]}x{shape[0]}"
    if not (isinstance(frame.frame_counter, int) and 0 <= frame.frame_counter < COUNTER_LIMIT):
        return f"frame counter {frame.frame_counter!r} is outside [0, 2**32)"
    if not (isinstance(frame.timestamp_us, int) and 0 <= frame.timestamp_us < TIMESTAMP_LIMIT_US):
        return f"device timestamp {frame.timestamp_us!r} us is outside [0, 2**63)"
    for name in ("host_monotonic_s", "host_wall_s"):
        if not math.isfinite(getattr(frame, name)):
            return f"{name} is {getattr(frame, name)!r}"
    return None
