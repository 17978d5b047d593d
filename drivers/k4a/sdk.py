"""Microsoft's Azure Kinect libraries (libk4a, libk4arecord) through ctypes: the copies pyk4a-bundle ships.

Only the bundled shared libraries are used, never the `pyk4a` Python module (its compiled part was built against
numpy 1.x and does not import under numpy 2). `load()` finds them beside the installed pyk4a package without
importing it and declares the prototypes of the functions tofd calls; the structures are the SDK's (k4atypes.h,
k4arecord/types.h). The SDK's own log messages go to this module's logger instead of stdout.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import importlib.util
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

DEPTH_MODE_VALUES = {"NFOV_2X2BINNED": 1, "NFOV_UNBINNED": 2, "WFOV_2X2BINNED": 3, "WFOV_UNBINNED": 4}
"""k4a_depth_mode_t of each depth mode with a depth image (0 is off, 5 PASSIVE_IR)."""
FPS_VALUES = {5: 0, 15: 1, 30: 2}
"""k4a_fps_t of each frame rate the device offers."""
IMAGE_FORMAT_COLOR_MJPG, IMAGE_FORMAT_DEPTH16, IMAGE_FORMAT_IR16 = 0, 4, 5
RESULT_SUCCEEDED = 0  # k4a_result_t
WAIT_SUCCEEDED, WAIT_FAILED, WAIT_TIMEOUT = 0, 1, 2  # k4a_wait_result_t
STREAM_SUCCEEDED, STREAM_FAILED, STREAM_EOF = 0, 1, 2  # k4a_stream_result_t
BUFFER_SUCCEEDED, BUFFER_FAILED, BUFFER_TOO_SMALL = 0, 1, 2  # k4a_buffer_result_t


class DeviceConfiguration(ctypes.Structure):
    """k4a_device_configuration_t."""

    _fields_ = [("color_format", ctypes.c_int), ("color_resolution", ctypes.c_int), ("depth_mode", ctypes.c_int),
                ("camera_fps", ctypes.c_int), ("synchronized_images_only", ctypes.c_bool),
                ("depth_delay_off_color_usec", ctypes.c_int32), ("wired_sync_mode", ctypes.c_int),
                ("subordinate_delay_off_master_usec", ctypes.c_uint32),
                ("disable_streaming_indicator", ctypes.c_bool)]


class RecordConfiguration(ctypes.Structure):
    """k4a_record_configuration_t: how a recording was made."""

    _fields_ = [("color_format", ctypes.c_int), ("color_resolution", ctypes.c_int), ("depth_mode", ctypes.c_int),
                ("camera_fps", ctypes.c_int), ("color_track_enabled", ctypes.c_bool),
                ("depth_track_enabled", ctypes.c_bool), ("ir_track_enabled", ctypes.c_bool),
                ("imu_track_enabled", ctypes.c_bool), ("depth_delay_off_color_usec", ctypes.c_int32),
                ("wired_sync_mode", ctypes.c_int), ("subordinate_delay_off_master_usec", ctypes.c_uint32),
                ("start_timestamp_offset_usec", ctypes.c_uint32)]


class Version(ctypes.Structure):
    """k4a_version_t."""

    _fields_ = [("major", ctypes.c_uint32), ("minor", ctypes.c_uint32), ("iteration", ctypes.c_uint32)]

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}.{self.iteration}"


class HardwareVersion(ctypes.Structure):
    """k4a_hardware_version_t."""

    _fields_ = [("rgb", Version), ("depth", Version), ("audio", Version), ("depth_sensor", Version),
                ("firmware_build", ctypes.c_int), ("firmware_signature", ctypes.c_int)]


LOG_LEVELS = {0: logging.WARNING, 1: logging.DEBUG, 2: logging.DEBUG}
"""k4a_log_level_t (critical, error, warning) -> the level tofd logs the SDK's message at: its errors are what it
says about expected conditions too ("No devices found"), so they are debug, and tofd reports what fails itself."""
LOG_MIN_LEVEL = 2  # K4A_LOG_LEVEL_WARNING
MESSAGE_CALLBACK = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_int,
                                    ctypes.c_char_p)


@MESSAGE_CALLBACK
def _forward_message(context: object, level: int, file: bytes | None, line: int, message: bytes | None) -> None:
    log.log(LOG_LEVELS.get(level, logging.DEBUG), "libk4a: %s", (message or b"").decode(errors="replace").strip())


class Libraries:
    """The loaded libk4a and libk4arecord with the prototypes of the functions tofd calls."""

    def __init__(self, k4a: ctypes.CDLL, record: ctypes.CDLL) -> None:
        self.k4a, self.record = k4a, record
        vp, c = ctypes.c_void_p, ctypes
        size_p = c.POINTER(c.c_size_t)
        for lib, name, args, res in (
            (k4a, "k4a_set_debug_message_handler", [MESSAGE_CALLBACK, vp, c.c_int], c.c_int),
            (k4a, "k4a_device_get_installed_count", [], c.c_uint32),
            (k4a, "k4a_device_open", [c.c_uint32, c.POINTER(vp)], c.c_int),
            (k4a, "k4a_device_close", [vp], None),
            (k4a, "k4a_device_get_serialnum", [vp, c.c_char_p, size_p], c.c_int),
            (k4a, "k4a_device_get_version", [vp, c.POINTER(HardwareVersion)], c.c_int),
            (k4a, "k4a_device_get_raw_calibration", [vp, c.c_char_p, size_p], c.c_int),
            (k4a, "k4a_device_start_cameras", [vp, c.POINTER(DeviceConfiguration)], c.c_int),
            (k4a, "k4a_device_stop_cameras", [vp], None),
            (k4a, "k4a_device_get_capture", [vp, c.POINTER(vp), c.c_int32], c.c_int),
            (k4a, "k4a_capture_get_depth_image", [vp], vp),
            (k4a, "k4a_capture_get_ir_image", [vp], vp),
            (k4a, "k4a_capture_release", [vp], None),
            (k4a, "k4a_image_get_buffer", [vp], c.POINTER(c.c_uint8)),
            (k4a, "k4a_image_get_size", [vp], c.c_size_t),
            (k4a, "k4a_image_get_width_pixels", [vp], c.c_int),
            (k4a, "k4a_image_get_height_pixels", [vp], c.c_int),
            (k4a, "k4a_image_get_stride_bytes", [vp], c.c_int),
            (k4a, "k4a_image_get_device_timestamp_usec", [vp], c.c_uint64),
            (k4a, "k4a_image_release", [vp], None),
            (record, "k4a_playback_open", [c.c_char_p, c.POINTER(vp)], c.c_int),
            (record, "k4a_playback_get_raw_calibration", [vp, c.c_char_p, size_p], c.c_int),
            (record, "k4a_playback_get_record_configuration", [vp, c.POINTER(RecordConfiguration)], c.c_int),
            (record, "k4a_playback_get_tag", [vp, c.c_char_p, c.c_char_p, size_p], c.c_int),
            (record, "k4a_playback_get_next_capture", [vp, c.POINTER(vp)], c.c_int),
            (record, "k4a_playback_close", [vp], None),
        ):
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = args, res
        k4a.k4a_set_debug_message_handler(_forward_message, None, LOG_MIN_LEVEL)


def read_buffer(call: object, *args: object) -> bytes | None:
    """The bytes of a k4a_buffer_result_t getter (called once for the size, once for the data), None if it fails;
    a trailing NUL (strings) is kept."""
    size = ctypes.c_size_t(0)
    result = call(*args, None, ctypes.byref(size))  # type: ignore[operator]
    if result not in (BUFFER_TOO_SMALL, BUFFER_SUCCEEDED) or size.value == 0:
        return None
    buffer = ctypes.create_string_buffer(size.value)
    if call(*args, buffer, ctypes.byref(size)) != BUFFER_SUCCEEDED:  # type: ignore[operator]
        return None
    return buffer.raw[: size.value]


def bundled_library_dir() -> Path | str:
    """pyk4a-bundle's library folder (found without importing pyk4a), or why there is none."""
    spec = importlib.util.find_spec("pyk4a")
    if spec is None or not spec.submodule_search_locations:
        return "pyk4a-bundle is not installed"
    return Path(next(iter(spec.submodule_search_locations))).parent / "pyk4a_bundle.libs"


@functools.cache
def load() -> Libraries | str:
    """The bundled libraries, loaded once; or a sentence saying why they cannot be."""
    libs = bundled_library_dir()
    if isinstance(libs, str):
        return libs
    k4a = sorted(glob.glob(str(libs / "libk4a-*.so*")))
    record = sorted(glob.glob(str(libs / "libk4arecord-*.so*")))
    if not k4a or not record:
        return f"no libk4a / libk4arecord in {libs} (pyk4a-bundle ships them for Linux x86-64)"
    os.environ.setdefault("K4A_ENABLE_LOG_TO_STDOUT", "0")  # the SDK's messages go to tofd's log instead
    try:
        mode = os.RTLD_GLOBAL  # libk4arecord resolves libk4a's symbols
        return Libraries(ctypes.CDLL(k4a[0], mode=mode), ctypes.CDLL(record[0], mode=mode))
    except OSError as exc:
        return f"libk4a / libk4arecord do not load: {exc}"
