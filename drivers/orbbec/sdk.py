"""The Orbbec SDK v2 C API (libOrbbecSDK, as the pyorbbecsdk2 wheel ships it) through ctypes.

tofd calls the SDK's C library rather than its Python binding: the binding's wheels pin numpy < 2 (before Python
3.12), opencv-python and a viewer's dependencies, and do not expose a lens's distortion model; the C API has no
Python pins and reports everything a camera knows. Each wrapper owns one SDK handle and deletes it on close();
every call checks the SDK's ob_error and raises OrbbecError with the SDK's message.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
from ctypes import POINTER, Structure, c_bool, c_char_p, c_float, c_int, c_int16, c_uint32, c_uint64, c_void_p
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tofd.drivers.source import DriverError

DISTRIBUTION = "pyorbbecsdk2"
"""The PyPI distribution whose wheel carries libOrbbecSDK.so (tofd's `orbbec` extra installs it)."""
LIBRARY_NAMES = ("libOrbbecSDK.so.2", "libOrbbecSDK.so")
LOG_OFF = 5  # OB_LOG_SEVERITY_OFF
LOG_ERROR = 3  # OB_LOG_SEVERITY_ERROR
SENSOR_IR, SENSOR_DEPTH, SENSOR_IR_LEFT = 1, 3, 6  # OBSensorType
FRAME_IR, FRAME_DEPTH, FRAME_IR_LEFT = 1, 3, 6  # OBFrameType
PERMISSION_READ = 1  # OB_PERMISSION_READ
PLAYBACK_STATUS = {0: "unknown", 1: "playing", 2: "paused", 3: "stopped"}  # OBPlaybackStatus
FORMAT_NAMES = {8: "Y16", 28: "Z16", 1: "Y8", 2: "I420", 27: "Y12", 26: "Y10", 30: "RVL"}
"""OBFormat -> name, for the formats of depth and IR streams."""


class OrbbecError(DriverError):
    """An Orbbec SDK call failed; the message is the SDK's, with the function that failed."""


class CameraIntrinsic(Structure):
    _fields_ = [("fx", c_float), ("fy", c_float), ("cx", c_float), ("cy", c_float), ("width", c_int16),
                ("height", c_int16)]


class IntRange(Structure):
    _fields_ = [("cur", ctypes.c_int32), ("max", ctypes.c_int32), ("min", ctypes.c_int32), ("step", ctypes.c_int32),
                ("default", ctypes.c_int32)]


class CameraDistortion(Structure):
    _fields_ = [("k1", c_float), ("k2", c_float), ("k3", c_float), ("k4", c_float), ("k5", c_float),
                ("k6", c_float), ("p1", c_float), ("p2", c_float), ("model", c_int)]


_P = c_void_p
_ERR = POINTER(c_void_p)
PROTOTYPES: dict[str, tuple[Any, tuple[Any, ...]]] = {
    "ob_set_logger_severity": (None, (c_int,)),
    "ob_set_logger_to_file": (None, (c_int, c_char_p)),
    "ob_set_logger_to_console": (None, (c_int,)),
    "ob_set_extensions_directory": (None, (c_char_p,)),
    "ob_create_context": (_P, ()),
    "ob_delete_context": (None, (_P,)),
    "ob_query_device_list": (_P, (_P,)),
    "ob_register_device_changed_callback": (c_uint64, (_P, _P, _P)),
    "ob_unregister_device_changed_callback": (None, (_P, c_uint64)),
    "ob_delete_device_list": (None, (_P,)),
    "ob_device_list_get_count": (c_uint32, (_P,)),
    "ob_device_list_get_device_serial_number": (c_char_p, (_P, c_uint32)),
    "ob_device_list_get_device": (_P, (_P, c_uint32)),
    "ob_device_list_get_device_name": (c_char_p, (_P, c_uint32)),
    "ob_delete_device": (None, (_P,)),
    "ob_device_get_device_info": (_P, (_P,)),
    "ob_delete_device_info": (None, (_P,)),
    "ob_device_info_get_name": (c_char_p, (_P,)),
    "ob_device_info_get_serial_number": (c_char_p, (_P,)),
    "ob_device_info_get_firmware_version": (c_char_p, (_P,)),
    "ob_device_info_get_connection_type": (c_char_p, (_P,)),
    "ob_device_is_property_supported": (c_bool, (_P, c_int, c_int)),
    "ob_device_get_int_property": (ctypes.c_int32, (_P, c_int)),
    "ob_device_get_int_property_range": (IntRange, (_P, c_int)),
    "ob_device_get_float_property": (c_float, (_P, c_int)),
    "ob_device_get_bool_property": (c_bool, (_P, c_int)),
    "ob_device_set_int_property": (None, (_P, c_int, ctypes.c_int32)),
    "ob_device_set_bool_property": (None, (_P, c_int, c_bool)),
    "ob_device_get_sensor_list": (_P, (_P,)),
    "ob_delete_sensor_list": (None, (_P,)),
    "ob_sensor_list_get_count": (c_uint32, (_P,)),
    "ob_sensor_list_get_sensor_type": (c_int, (_P, c_uint32)),
    "ob_create_pipeline_with_device": (_P, (_P,)),
    "ob_delete_pipeline": (None, (_P,)),
    "ob_pipeline_get_stream_profile_list": (_P, (_P, c_int)),
    "ob_pipeline_start_with_config": (None, (_P, _P)),
    "ob_pipeline_stop": (None, (_P,)),
    "ob_pipeline_wait_for_frameset": (_P, (_P, c_uint32)),
    "ob_create_config": (_P, ()),
    "ob_delete_config": (None, (_P,)),
    "ob_config_enable_stream_with_stream_profile": (None, (_P, _P)),
    "ob_stream_profile_list_get_count": (c_uint32, (_P,)),
    "ob_stream_profile_list_get_profile": (_P, (_P, c_int)),
    "ob_delete_stream_profile_list": (None, (_P,)),
    "ob_delete_stream_profile": (None, (_P,)),
    "ob_stream_profile_get_format": (c_int, (_P,)),
    "ob_video_stream_profile_get_width": (c_uint32, (_P,)),
    "ob_video_stream_profile_get_height": (c_uint32, (_P,)),
    "ob_video_stream_profile_get_fps": (c_uint32, (_P,)),
    "ob_video_stream_profile_get_intrinsic": (CameraIntrinsic, (_P,)),
    "ob_video_stream_profile_get_distortion": (CameraDistortion, (_P,)),
    "ob_frameset_get_frame": (_P, (_P, c_int)),
    "ob_delete_frame": (None, (_P,)),
    "ob_frame_get_index": (c_uint64, (_P,)),
    "ob_frame_get_timestamp_us": (c_uint64, (_P,)),
    "ob_frame_get_format": (c_int, (_P,)),
    "ob_frame_get_data": (POINTER(ctypes.c_uint8), (_P,)),
    "ob_frame_get_data_size": (c_uint32, (_P,)),
    "ob_video_frame_get_width": (c_uint32, (_P,)),
    "ob_video_frame_get_height": (c_uint32, (_P,)),
    "ob_depth_frame_get_value_scale": (c_float, (_P,)),
    "ob_create_playback_device": (_P, (c_char_p,)),
    "ob_playback_device_pause": (None, (_P,)),
    "ob_playback_device_resume": (None, (_P,)),
    "ob_playback_device_get_current_playback_status": (c_int, (_P,)),
    "ob_playback_device_get_position": (c_uint64, (_P,)),
    "ob_playback_device_get_duration": (c_uint64, (_P,)),
}
"""The C functions tofd calls: name -> (return type, argument types before the trailing ob_error **)."""
DEVICE_CHANGED = ctypes.CFUNCTYPE(None, c_void_p, c_void_p, c_void_p)  # ob_device_changed_callback


def library_path() -> Path:
    """libOrbbecSDK.so of the installed pyorbbecsdk2 wheel; OrbbecError naming the distribution if none."""
    try:
        files = importlib.metadata.distribution(DISTRIBUTION).files or []
    except importlib.metadata.PackageNotFoundError:
        raise OrbbecError(f"{DISTRIBUTION} is not installed") from None
    found = {f.name: f for f in files}
    for name in LIBRARY_NAMES:
        if name in found:
            return Path(str(found[name].locate()))
    raise OrbbecError(f"{DISTRIBUTION} is installed but holds no {' or '.join(LIBRARY_NAMES)}")


class Sdk:
    """The loaded library: `call(name, *args)` runs one C function and raises OrbbecError on its ob_error."""

    def __init__(self, path: Path) -> None:
        try:
            self.lib = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        except OSError as exc:
            raise OrbbecError(f"cannot load {path}: {exc}") from None
        for name, (restype, argtypes) in PROTOTYPES.items():
            function = getattr(self.lib, name)
            function.restype = restype
            function.argtypes = [*argtypes, _ERR]
        self.lib.ob_error_get_message.restype = c_char_p
        self.lib.ob_error_get_message.argtypes = [c_void_p]
        self.lib.ob_error_get_function.restype = c_char_p
        self.lib.ob_error_get_function.argtypes = [c_void_p]
        self.lib.ob_delete_error.argtypes = [c_void_p]
        self.version = ".".join(str(getattr(self.lib, f"ob_get_{p}_version")()) for p in ("major", "minor", "patch"))
        extensions = path.parent / "extensions"  # the depth engine (Femto), filters, firmware updater
        if extensions.is_dir():
            self.call("ob_set_extensions_directory", str(extensions).encode())
        self.call("ob_set_logger_to_file", LOG_OFF, b"")  # the SDK's default logs into ./Log of the cwd
        self.call("ob_set_logger_to_console", LOG_ERROR)

    def call(self, name: str, *args: Any) -> Any:
        error = c_void_p()
        result = getattr(self.lib, name)(*args, ctypes.byref(error))
        if error.value:
            message = (self.lib.ob_error_get_message(error) or b"").decode(errors="replace")
            self.lib.ob_delete_error(error)
            raise OrbbecError(f"Orbbec SDK {name}: {message}")
        return result

    def text(self, name: str, *args: Any) -> str:
        value = self.call(name, *args)
        return value.decode(errors="replace") if value else ""


_loaded: Sdk | None = None


def load() -> Sdk:
    """The SDK library, loaded once per process; OrbbecError when it is not installed or cannot load."""
    global _loaded
    if _loaded is None:
        _loaded = Sdk(library_path())
    return _loaded


@dataclass(frozen=True, slots=True)
class Profile:
    """One video stream profile the device offers, with its lens (pixel size, [fx, fy, cx, cy],
    OBCameraDistortionModel and the SDK's [k1, k2, k3, k4, k5, k6, p1, p2])."""

    handle: int
    width: int
    height: int
    fps: int
    format: int
    k: tuple[float, float, float, float]
    distortion_model: int
    distortion: tuple[float, ...]

    def describe(self) -> str:
        return f"{self.width}x{self.height} @ {self.fps} fps {FORMAT_NAMES.get(self.format, f'format {self.format}')}"


def read_profile(sdk: Sdk, handle: int) -> Profile:
    """The fields of a video stream profile handle (still owned by the caller)."""
    k = sdk.call("ob_video_stream_profile_get_intrinsic", handle)
    d = sdk.call("ob_video_stream_profile_get_distortion", handle)
    return Profile(handle, sdk.call("ob_video_stream_profile_get_width", handle),
                   sdk.call("ob_video_stream_profile_get_height", handle),
                   sdk.call("ob_video_stream_profile_get_fps", handle),
                   sdk.call("ob_stream_profile_get_format", handle), (k.fx, k.fy, k.cx, k.cy), d.model,
                   (d.k1, d.k2, d.k3, d.k4, d.k5, d.k6, d.p1, d.p2))


@dataclass(frozen=True, slots=True)
class FrameData:
    """One image of a frameset, copied out of the SDK's buffer."""

    image: np.ndarray  # (H, W) uint16 (Y16 / Z16) or uint8 (Y8)
    index: int  # the device's frame number
    timestamp_us: int  # device clock
    value_scale: float  # depth frames: millimetres per value; 0 for others


def frame_data(sdk: Sdk, frameset: int, frame_type: int) -> FrameData | None:
    """The frame of `frame_type` in a frameset (None if it has none), its pixels copied; the frame is released."""
    frame = sdk.call("ob_frameset_get_frame", frameset, frame_type)
    if not frame:
        return None
    try:
        width, height = sdk.call("ob_video_frame_get_width", frame), sdk.call("ob_video_frame_get_height", frame)
        size = sdk.call("ob_frame_get_data_size", frame)
        bytes_per_pixel = size // max(1, width * height)
        if bytes_per_pixel not in (1, 2) or size != width * height * bytes_per_pixel:
            fmt = sdk.call("ob_frame_get_format", frame)
            raise OrbbecError(f"Orbbec frame of {width}x{height} holds {size} bytes in format "
                              f"{FORMAT_NAMES.get(fmt, fmt)}: tofd reads 8- or 16-bit single-channel images")
        buffer = ctypes.string_at(sdk.call("ob_frame_get_data", frame), size)
        image = np.frombuffer(buffer, np.uint16 if bytes_per_pixel == 2 else np.uint8).reshape(height, width)
        scale = sdk.call("ob_depth_frame_get_value_scale", frame) if frame_type == FRAME_DEPTH else 0.0
        return FrameData(image, sdk.call("ob_frame_get_index", frame), sdk.call("ob_frame_get_timestamp_us", frame),
                         float(scale))
    finally:
        sdk.call("ob_delete_frame", frame)
