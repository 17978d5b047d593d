"""Driver layer: turns a camera (SR3000-style USB, emulated) or a recording into a stream of Frames."""

from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics

__all__ = ["DeviceInfo", "Frame", "GroundTruth", "Intrinsics", "Registers", "SensorInfo"]
