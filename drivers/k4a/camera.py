"""The Azure Kinect (and Orbbec Femto in its K4A mode) as a live camera through libk4a, or a recording played by
libk4arecord as its device (`--playback FILE`, in real time).

A device: k4a_device_open (the camera of request.serial, else the first), its raw calibration, then
k4a_device_start_cameras in the requested depth mode and frame rate and k4a_device_get_capture. A recording:
k4a_playback_open, its raw calibration and record configuration, k4a_playback_get_next_capture (the same capture
objects a device gives), delivered at the pace of their device timestamps. Both feed the same conversion
(tofd.drivers.live.SdkCamera.frame): DEPTH16 z-depth in millimetres (0 = no return) to radial range through the
depth mode's lens (tofd.drivers.k4a.lens: Brown-Conrady with k1-k6, p1, p2, from the device's own calibration),
IR16 as the amplitude, the device timestamp. The device has no frame counter: a frame's counter is its time since
the first capture in frame periods, so a capture the device dropped leaves a gap. Captures without a depth and an
IR image (colour-only, IMU) are passed over. The depth camera has no exposure or laser power setting.
"""

from __future__ import annotations

import ctypes
import json
import logging
import time
from pathlib import Path

import numpy as np

from tofd.drivers.cameras import CameraListing, CameraRequest, StreamMode
from tofd.drivers.frame import DeviceInfo, SensorInfo
from tofd.drivers.k4a import sdk
from tofd.drivers.k4a.lens import DEPTH_MODES, depth_lens
from tofd.drivers.k4a.mkv import device_model
from tofd.drivers.live import Capture, DeviceLost, PlaybackEnded, SdkCamera
from tofd.drivers.source import DriverError

log = logging.getLogger(__name__)

_LOADED = sdk.load()
if isinstance(_LOADED, str):
    raise ImportError(_LOADED)
LIBS: sdk.Libraries = _LOADED

KIND = "k4a"
DEFAULT_DEPTH_MODE = "NFOV_UNBINNED"
MAX_FPS = {"NFOV_2X2BINNED": 30, "NFOV_UNBINNED": 30, "WFOV_2X2BINNED": 30, "WFOV_UNBINNED": 15}
"""The highest frame rate of each depth mode (the SDK refuses WFOV_UNBINNED at 30 fps)."""


def stream_mode(mode: StreamMode) -> tuple[str, int]:
    """(depth mode, fps) of a request: the depth mode named, else the one of the requested size, else
    NFOV_UNBINNED; fps as asked, else the mode's highest. DriverError naming what the device offers."""
    offered = "; ".join(f"{name} {g.output[0]}x{g.output[1]} at "
                        + "/".join(str(f) for f in sdk.FPS_VALUES if f <= MAX_FPS[name]) + " fps"
                        for name, g in DEPTH_MODES.items() if name in MAX_FPS)
    name = mode.depth_mode
    if name is None and (mode.width or mode.height):
        sizes = [n for n, g in DEPTH_MODES.items() if n in MAX_FPS and (mode.width or g.output[0], mode.height
                                                                         or g.output[1]) == g.output]
        if not sizes:
            raise DriverError(f"k4a camera: no depth mode makes {mode.width or '?'}x{mode.height or '?'} images; "
                              f"the Azure Kinect offers {offered}")
        name = sizes[0]
    name = name or DEFAULT_DEPTH_MODE
    if name not in MAX_FPS:
        raise DriverError(f"k4a camera: depth mode {name!r} has no depth image; the Azure Kinect offers {offered}")
    w, h = DEPTH_MODES[name].output
    if (mode.width or w, mode.height or h) != (w, h):
        raise DriverError(f"k4a camera: depth mode {name} makes {w}x{h} images, not {mode.width or w}x"
                          f"{mode.height or h}; the Azure Kinect offers {offered}")
    fps = mode.fps or MAX_FPS[name]
    if fps not in sdk.FPS_VALUES or fps > MAX_FPS[name]:
        raise DriverError(f"k4a camera: {fps} fps is not offered in {name}; the Azure Kinect offers {offered}")
    return name, fps


def _image(image: int | None, what: str) -> np.ndarray:
    """(H, W) uint16 copy of a DEPTH16 / IR16 k4a_image_t's pixels (the image is released)."""
    try:
        w, h = LIBS.k4a.k4a_image_get_width_pixels(image), LIBS.k4a.k4a_image_get_height_pixels(image)
        stride = LIBS.k4a.k4a_image_get_stride_bytes(image)
        if w <= 0 or h <= 0 or stride < 2 * w or LIBS.k4a.k4a_image_get_size(image) < h * stride:
            raise DriverError(f"k4a camera: a {what} image of {w}x{h} pixels, stride {stride}")
        raw = np.ctypeslib.as_array(LIBS.k4a.k4a_image_get_buffer(image), shape=(h * stride,))
        return raw.view("<u2").reshape(h, stride // 2)[:, :w].copy()
    finally:
        LIBS.k4a.k4a_image_release(image)


class K4aCamera(SdkCamera):
    """An Azure Kinect, or a recording libk4arecord plays as one (request.playback), as a stream of Frames."""

    def __init__(self, request: CameraRequest) -> None:
        super().__init__(request)
        if request.settings:
            raise DriverError(f"k4a camera: the Azure Kinect's depth camera has no {', '.join(request.settings)} "
                              "setting (leave [camera] exposure_us = 0 and laser_power = -1)")
        self.depth_mode, self.fps = stream_mode(request.mode)
        self._device: ctypes.c_void_p | None = None
        self._playback: ctypes.c_void_p | None = None
        self._pending: Capture | None = None  # a played capture not yet due
        self._clock0: tuple[int, float] | None = None  # (device us, host monotonic s) of the first capture played
        self._first_us: int | None = None
        self._last_counter = -1
        self._opened_serial = ""  # the device opened first: a reconnect reopens this one

    # ------------------------------------------------------------------------------------------- open
    def _open(self) -> None:
        if self.request.playback is not None:
            self._open_playback(self.request.playback)
        else:
            self._open_device()
        self._pending, self._clock0 = None, None

    def _describe(self, raw: bytes, serial: str, firmware: str) -> None:
        """Intrinsics, device and sensor from a raw calibration.json."""
        try:
            self.intrinsics = depth_lens(raw, self.depth_mode).intrinsics
            calibration = json.loads(raw)
        except ValueError as exc:
            raise DriverError(f"k4a camera {serial}: its calibration: {exc}") from None
        self.device_info = DeviceInfo(serial=serial, firmware=firmware, backend=KIND, model=device_model(calibration))
        self.sensor = SensorInfo(depth_unit_m=1e-3, amplitude="ir", invalid_value=0, amplitude_full_scale=65535.0,
                                 frame_period_s=1 / self.fps,
                                 settings={"K4A_DEPTH_MODE": self.depth_mode, "K4A_FPS": f"FPS_{self.fps}"})

    def _open_device(self) -> None:
        """The device of request.serial, else the first; after a reconnect the one opened before (its serial)."""
        wanted = self.request.serial or self._opened_serial
        count = LIBS.k4a.k4a_device_get_installed_count()
        for index in range(count):
            handle = ctypes.c_void_p()
            if LIBS.k4a.k4a_device_open(index, ctypes.byref(handle)) != sdk.RESULT_SUCCEEDED:
                continue
            serial = (sdk.read_buffer(LIBS.k4a.k4a_device_get_serialnum, handle) or b"").rstrip(b"\0").decode()
            if wanted and serial != wanted:
                LIBS.k4a.k4a_device_close(handle)
                continue
            try:
                self._start(handle, serial)
            except DriverError:
                LIBS.k4a.k4a_device_close(handle)
                raise
            self._device, self._opened_serial = handle, serial
            return
        which = f"serial {wanted}" if wanted else "any"
        raise DriverError(f"k4a camera: no Azure Kinect ({which}) could be opened; {count} attached")

    def _start(self, handle: ctypes.c_void_p, serial: str) -> None:
        version = sdk.HardwareVersion()
        firmware = str(version.depth) if LIBS.k4a.k4a_device_get_version(handle, ctypes.byref(version)) == 0 else ""
        raw = sdk.read_buffer(LIBS.k4a.k4a_device_get_raw_calibration, handle)
        if raw is None:
            raise DriverError(f"k4a camera {serial}: the device gave no calibration")
        self._describe(raw.rstrip(b"\0"), serial, firmware)
        config = sdk.DeviceConfiguration(depth_mode=sdk.DEPTH_MODE_VALUES[self.depth_mode],
                                         camera_fps=sdk.FPS_VALUES[self.fps], synchronized_images_only=False)
        if LIBS.k4a.k4a_device_start_cameras(handle, ctypes.byref(config)) != sdk.RESULT_SUCCEEDED:
            raise DriverError(f"k4a camera {serial}: the device refused to start {self.depth_mode} at {self.fps} fps")

    def _open_playback(self, path: Path) -> None:
        handle = ctypes.c_void_p()
        if LIBS.record.k4a_playback_open(str(path).encode(), ctypes.byref(handle)) != sdk.RESULT_SUCCEEDED:
            raise DriverError(f"{path}: libk4arecord cannot open it as an Azure Kinect recording")
        try:
            config = sdk.RecordConfiguration()
            LIBS.record.k4a_playback_get_record_configuration(handle, ctypes.byref(config))
            modes = {v: k for k, v in sdk.DEPTH_MODE_VALUES.items()}
            rates = {v: k for k, v in sdk.FPS_VALUES.items()}
            recorded = modes.get(config.depth_mode), rates.get(config.camera_fps)
            if recorded[0] is None or not (config.depth_track_enabled and config.ir_track_enabled):
                raise DriverError(f"{path}: the recording has no depth and IR tracks (depth mode value "
                                  f"{config.depth_mode})")
            asked = self.request.mode
            if (asked.depth_mode or asked.width or asked.height or asked.fps) and \
                    (self.depth_mode, self.fps) != recorded:
                raise DriverError(f"{path}: recorded in {recorded[0]} at {recorded[1]} fps, not {self.depth_mode} "
                                  f"at {self.fps} fps as asked")
            self.depth_mode, self.fps = str(recorded[0]), int(recorded[1] or MAX_FPS[str(recorded[0])])
            raw = sdk.read_buffer(LIBS.record.k4a_playback_get_raw_calibration, handle)
            if raw is None:
                raise DriverError(f"{path}: the recording has no device calibration")
            serial = sdk.read_buffer(LIBS.record.k4a_playback_get_tag, handle, b"K4A_DEVICE_SERIAL_NUMBER") or b""
            firmware = sdk.read_buffer(LIBS.record.k4a_playback_get_tag, handle, b"K4A_DEPTH_FIRMWARE_VERSION") or b""
            self._describe(raw.rstrip(b"\0"), serial.rstrip(b"\0").decode(errors="replace"),
                           firmware.rstrip(b"\0").decode(errors="replace"))
        except DriverError:
            LIBS.record.k4a_playback_close(handle)
            raise
        self._playback = handle

    # ------------------------------------------------------------------------------------------- wait
    def _capture(self, capture: ctypes.c_void_p) -> Capture | None:
        """The Capture of a k4a_capture_t with depth and IR (released), None for one without (colour, IMU)."""
        try:
            depth = LIBS.k4a.k4a_capture_get_depth_image(capture)
            ir = LIBS.k4a.k4a_capture_get_ir_image(capture)
            if not depth or not ir:
                for image in (depth, ir):
                    if image:
                        LIBS.k4a.k4a_image_release(image)
                return None
            timestamp_us = int(LIBS.k4a.k4a_image_get_device_timestamp_usec(depth))
            try:
                depth_mm = _image(depth, "depth")
            except DriverError:
                LIBS.k4a.k4a_image_release(ir)
                raise
            ir16 = _image(ir, "IR")
        finally:
            LIBS.k4a.k4a_capture_release(capture)
        if self._first_us is None:
            self._first_us = timestamp_us
        counter = max(self._last_counter + 1, round((timestamp_us - self._first_us) * self.fps / 1e6))
        self._last_counter = counter
        return Capture(depth=depth_mm, amplitude=ir16, frame_counter=counter, timestamp_us=timestamp_us)

    def _wait(self, timeout_s: float) -> Capture | None:
        if self._playback is not None:
            return self._wait_playback(timeout_s)
        if self._device is None:
            raise DeviceLost("the device is not open")
        capture = ctypes.c_void_p()
        result = LIBS.k4a.k4a_device_get_capture(self._device, ctypes.byref(capture), max(1, round(timeout_s * 1e3)))
        if result == sdk.WAIT_TIMEOUT:
            return None
        if result != sdk.WAIT_SUCCEEDED:
            raise DeviceLost("k4a_device_get_capture failed")
        return self._capture(capture)

    def _wait_playback(self, timeout_s: float) -> Capture | None:
        """The next played capture at its time (device timestamps from the first, on the host's clock)."""
        assert self._playback is not None
        while self._pending is None:
            handle = ctypes.c_void_p()
            result = LIBS.record.k4a_playback_get_next_capture(self._playback, ctypes.byref(handle))
            if result == sdk.STREAM_EOF:
                raise PlaybackEnded()
            if result != sdk.STREAM_SUCCEEDED:
                self.counters["corrupt_tail"] += 1
                log.warning("%s: libk4arecord cannot read on; the playback ends", self.request.playback)
                raise PlaybackEnded()
            self._pending = self._capture(handle)
        if self._clock0 is None:
            self._clock0 = (self._pending.timestamp_us, time.monotonic())
        due = self._clock0[1] + (self._pending.timestamp_us - self._clock0[0]) / 1e6
        wait = due - time.monotonic()
        if wait > timeout_s:
            time.sleep(timeout_s)
            return None
        time.sleep(max(0.0, wait))
        capture, self._pending = self._pending, None
        return capture

    def _stop(self) -> None:
        if self._device is not None:
            LIBS.k4a.k4a_device_stop_cameras(self._device)
            LIBS.k4a.k4a_device_close(self._device)
            self._device = None
        if self._playback is not None:
            LIBS.record.k4a_playback_close(self._playback)
            self._playback = None


class K4aBackend:
    """The k4a kind of tofd.drivers.cameras: Azure Kinect devices through libk4a."""

    kind = KIND
    extra = "k4a"

    def list_cameras(self) -> list[CameraListing]:
        listings = []
        for index in range(LIBS.k4a.k4a_device_get_installed_count()):
            handle = ctypes.c_void_p()
            if LIBS.k4a.k4a_device_open(index, ctypes.byref(handle)) != sdk.RESULT_SUCCEEDED:
                listings.append(CameraListing(KIND, "Azure Kinect", "?", detail=f"device {index} cannot be opened "
                                              "(in use by another program?)"))
                continue
            try:
                serial = (sdk.read_buffer(LIBS.k4a.k4a_device_get_serialnum, handle) or b"").rstrip(b"\0").decode()
                version = sdk.HardwareVersion()
                ok = LIBS.k4a.k4a_device_get_version(handle, ctypes.byref(version)) == sdk.RESULT_SUCCEEDED
                listings.append(CameraListing(KIND, "Azure Kinect", serial, str(version.depth) if ok else "",
                                              detail=f"device {index}"))
            finally:
                LIBS.k4a.k4a_device_close(handle)
        return listings

    def open(self, request: CameraRequest) -> K4aCamera:
        return K4aCamera.opened(request)


BACKEND = K4aBackend()
