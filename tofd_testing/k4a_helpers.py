"""Microsoft's Azure Kinect libraries (libk4a, libk4arecord from the pyk4a-bundle wheel) through ctypes, for tests:
recordings written by the SDK's own recorder and the SDK's calibration as the reference for tofd's lens model.

tofd never imports this module or the pyk4a module; `k4a_libraries()` skips the calling test when the wheel or its
libraries are missing (pyk4a-bundle ships Linux x86-64 and Windows builds only).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import numpy as np
import pytest

from tofd.drivers.k4a import sdk

CALIBRATION_JSON = Path(__file__).resolve().parents[1] / "tests" / "data" / "k4a_calibration.json"
"""Factory calibration of a real Azure Kinect (serial 001514394512), as pyk4a's test assets ship it."""

DEPTH_MODES = sdk.DEPTH_MODE_VALUES
COLOR_RESOLUTION_720P = 1
FPS = sdk.FPS_VALUES
IMU_RATE_HZ = 1600
"""The Azure Kinect's accelerometer / gyroscope sample rate (k4arecorder records the IMU by default)."""
CALIBRATION_TYPE_DEPTH = 0


class Extrinsics(ctypes.Structure):
    _fields_ = [("rotation", ctypes.c_float * 9), ("translation", ctypes.c_float * 3)]


class CameraCalibration(ctypes.Structure):
    """k4a_calibration_camera_t: parameters = cx, cy, fx, fy, k1..k6, codx, cody, p2, p1, metric_radius."""

    _fields_ = [("extrinsics", Extrinsics), ("model_type", ctypes.c_int), ("parameter_count", ctypes.c_uint),
                ("parameters", ctypes.c_float * 15), ("resolution_width", ctypes.c_int),
                ("resolution_height", ctypes.c_int), ("metric_radius", ctypes.c_float)]


class Calibration(ctypes.Structure):
    _fields_ = [("depth", CameraCalibration), ("color", CameraCalibration), ("extrinsics", Extrinsics * 16),
                ("depth_mode", ctypes.c_int), ("color_resolution", ctypes.c_int)]


class Float3(ctypes.Structure):
    _fields_ = [("x", ctypes.c_float), ("y", ctypes.c_float), ("z", ctypes.c_float)]


class ImuSample(ctypes.Structure):
    """k4a_imu_sample_t."""

    _fields_ = [("temperature", ctypes.c_float), ("acc_sample", Float3), ("acc_timestamp_usec", ctypes.c_uint64),
                ("gyro_sample", Float3), ("gyro_timestamp_usec", ctypes.c_uint64)]


RELEASE_CB = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)


class K4A:
    """The loaded libk4a and libk4arecord (tofd.drivers.k4a.sdk) with the prototypes of the recorder's functions and
    the others the tests call."""

    def __init__(self, libraries: sdk.Libraries) -> None:
        self.k4a, self.record = k4a, record = libraries.k4a, libraries.record
        vp, c = ctypes.c_void_p, ctypes
        for lib, name, args, res in (
            (record, "k4a_record_create", [c.c_char_p, vp, sdk.DeviceConfiguration, c.POINTER(vp)], c.c_int),
            (record, "k4a_record_add_tag", [vp, c.c_char_p, c.c_char_p], c.c_int),
            (record, "k4a_record_add_attachment", [vp, c.c_char_p, c.c_char_p, c.c_size_t], c.c_int),
            (record, "k4a_record_add_imu_track", [vp], c.c_int),
            (record, "k4a_record_write_header", [vp], c.c_int),
            (record, "k4a_record_write_imu_sample", [vp, ImuSample], c.c_int),
            (record, "k4a_record_write_capture", [vp, vp], c.c_int),
            (record, "k4a_record_flush", [vp], c.c_int),
            (record, "k4a_record_close", [vp], None),
            (k4a, "k4a_capture_create", [c.POINTER(vp)], c.c_int),
            (k4a, "k4a_capture_set_depth_image", [vp, vp], None),
            (k4a, "k4a_capture_set_ir_image", [vp, vp], None),
            (k4a, "k4a_capture_set_color_image", [vp, vp], None),
            (k4a, "k4a_image_create_from_buffer", [c.c_int, c.c_int, c.c_int, c.c_int, vp, c.c_size_t, RELEASE_CB,
                                                   vp, c.POINTER(vp)], c.c_int),
            (k4a, "k4a_image_create", [c.c_int, c.c_int, c.c_int, c.c_int, c.POINTER(vp)], c.c_int),
            (k4a, "k4a_image_set_device_timestamp_usec", [vp, c.c_uint64], None),
            (k4a, "k4a_calibration_get_from_raw", [c.c_char_p, c.c_size_t, c.c_int, c.c_int,
                                                   c.POINTER(Calibration)], c.c_int),
            (k4a, "k4a_calibration_2d_to_3d", [c.POINTER(Calibration), c.POINTER(c.c_float * 2), c.c_float, c.c_int,
                                               c.c_int, c.POINTER(c.c_float * 3), c.POINTER(c.c_int)], c.c_int),
        ):
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = args, res

    def calibration(self, raw: bytes, depth_mode: str) -> Calibration:
        """k4a_calibration_get_from_raw for a depth mode (colour camera off)."""
        cal = Calibration()
        buf = ctypes.create_string_buffer(raw)
        assert self.k4a.k4a_calibration_get_from_raw(buf, len(raw) + 1, DEPTH_MODES[depth_mode], 0,
                                                     ctypes.byref(cal)) == 0, depth_mode
        return cal

    def unproject(self, cal: Calibration, uv: np.ndarray, depth_mm: float = 1000.0) -> np.ndarray:
        """(N, 3) k4a_calibration_2d_to_3d of (N, 2) pixels at `depth_mm` (mm; NaN where the SDK says invalid)."""
        out = np.full((len(uv), 3), np.nan)
        point, p3, valid = (ctypes.c_float * 2)(), (ctypes.c_float * 3)(), ctypes.c_int()
        for i, (u, v) in enumerate(uv):
            point[0], point[1] = u, v
            assert self.k4a.k4a_calibration_2d_to_3d(ctypes.byref(cal), ctypes.byref(point), depth_mm,
                                                     CALIBRATION_TYPE_DEPTH, CALIBRATION_TYPE_DEPTH,
                                                     ctypes.byref(p3), ctypes.byref(valid)) == 0
            if valid.value:
                out[i] = list(p3)
        return out

    def _image(self, fmt: int, plane: np.ndarray, timestamp_us: int) -> ctypes.c_void_p:
        h, w = plane.shape
        image = ctypes.c_void_p()
        assert self.k4a.k4a_image_create(fmt, w, h, w * 2, ctypes.byref(image)) == 0
        ctypes.memmove(self.k4a.k4a_image_get_buffer(image), np.ascontiguousarray(plane, "<u2").ctypes.data, h * w * 2)
        self.k4a.k4a_image_set_device_timestamp_usec(image, timestamp_us)
        return image

    def _colour(self, timestamp_us: int, keep: list) -> ctypes.c_void_p:
        """A 1280x720 MJPG colour image over a constant JPEG (neither recorder nor playback decode it)."""
        data = ctypes.create_string_buffer(JPEG_STUB)
        keep.append(data)  # the recorder holds the image until its cluster is written
        image = ctypes.c_void_p()
        assert self.k4a.k4a_image_create_from_buffer(sdk.IMAGE_FORMAT_COLOR_MJPG, 1280, 720, 0, ctypes.addressof(data),
                                                     len(JPEG_STUB), _NO_RELEASE, None, ctypes.byref(image)) == 0
        self.k4a.k4a_image_set_device_timestamp_usec(image, timestamp_us)
        return image

    def write_recording(self, path: Path, depth_mode: str, depth: list[np.ndarray], ir: list[np.ndarray],
                        timestamps_us: list[int], *, fps: int = 30, calibration: bytes | None = None,
                        serial: str | None = None, imu: bool = False, colour_us: list[int] | tuple = ()) -> Path:
        """A recording by libk4arecord: one capture (uint16 depth in mm, uint16 IR) per timestamp; the raw
        calibration as the calibration.json attachment and the serial as tag, as the recorder adds a device's.
        With `imu`, an IMU track with a sample every 1/1600 s from the first time written (depth or colour) to one
        frame period after the last, as the device's IMU runs on until the recorder stops; `colour_us`: MJPG colour
        images at these device times (in the depth capture of the same time, else a colour-only capture), as
        k4arecorder writes a colour camera's."""
        config = sdk.DeviceConfiguration(color_format=sdk.IMAGE_FORMAT_COLOR_MJPG if colour_us else 0,
                                     color_resolution=COLOR_RESOLUTION_720P if colour_us else 0,
                                     depth_mode=DEPTH_MODES[depth_mode], camera_fps=FPS[fps], wired_sync_mode=0)
        handle = ctypes.c_void_p()
        assert self.record.k4a_record_create(str(path).encode(), None, config, ctypes.byref(handle)) == 0
        keep: list = []
        try:
            if serial is not None:
                assert self.record.k4a_record_add_tag(handle, b"K4A_DEVICE_SERIAL_NUMBER", serial.encode()) == 0
            if calibration is not None:
                assert self.record.k4a_record_add_attachment(handle, b"calibration.json", calibration,
                                                             len(calibration)) == 0
                assert self.record.k4a_record_add_tag(handle, b"K4A_CALIBRATION_FILE", b"calibration.json") == 0
            if imu:
                assert self.record.k4a_record_add_imu_track(handle) == 0
            assert self.record.k4a_record_write_header(handle) == 0
            planes = dict(zip(timestamps_us, zip(depth, ir, strict=True), strict=True))
            times = sorted(set(planes) | set(colour_us))
            imu_end = times[-1] + 1_000_000 // fps if imu and times else 0
            imu_us = iter(range(times[0], imu_end, 1_000_000 // IMU_RATE_HZ) if imu else ())
            next_imu = next(imu_us, None)

            def write_imu(until_us: float) -> None:
                nonlocal next_imu
                while next_imu is not None and next_imu <= until_us:
                    sample = ImuSample(temperature=30.0, acc_sample=Float3(0.0, 0.0, -9.81),
                                       acc_timestamp_usec=next_imu, gyro_timestamp_usec=next_imu)
                    assert self.record.k4a_record_write_imu_sample(handle, sample) == 0
                    next_imu = next(imu_us, None)

            for t in times:
                write_imu(t)
                capture = ctypes.c_void_p()
                assert self.k4a.k4a_capture_create(ctypes.byref(capture)) == 0
                images = []
                if t in planes:
                    images = [self._image(sdk.IMAGE_FORMAT_DEPTH16, planes[t][0], t),
                              self._image(sdk.IMAGE_FORMAT_IR16, planes[t][1], t)]
                    self.k4a.k4a_capture_set_depth_image(capture, images[0])
                    self.k4a.k4a_capture_set_ir_image(capture, images[1])
                if t in colour_us:
                    images.append(self._colour(t, keep))
                    self.k4a.k4a_capture_set_color_image(capture, images[-1])
                for image in images:
                    self.k4a.k4a_image_release(image)
                assert self.record.k4a_record_write_capture(handle, capture) == 0
                self.k4a.k4a_capture_release(capture)
            write_imu(float("inf"))  # the IMU goes on until the recorder stops, past the last capture
            assert self.record.k4a_record_flush(handle) == 0
        finally:
            self.record.k4a_record_close(handle)
        return path

    def playback_depth_times(self, path: Path) -> list[int]:
        """Device timestamps (us) of the depth images Microsoft's playback (k4a_playback_get_next_capture) reads
        from a recording, in order."""
        handle, capture, times = ctypes.c_void_p(), ctypes.c_void_p(), []
        assert self.record.k4a_playback_open(str(path).encode(), ctypes.byref(handle)) == 0, path
        try:
            # k4a_stream_result_t: 0 succeeded, 1 failed, 2 end of file
            while self.record.k4a_playback_get_next_capture(handle, ctypes.byref(capture)) == 0:
                depth = self.k4a.k4a_capture_get_depth_image(capture)
                if depth:
                    times.append(int(self.k4a.k4a_image_get_device_timestamp_usec(depth)))
                    self.k4a.k4a_image_release(depth)
                self.k4a.k4a_capture_release(capture)
        finally:
            self.record.k4a_playback_close(handle)
        return times


JPEG_STUB = bytes.fromhex("ffd8ffe000104a46494600010100000100010000ffd9")
"""A JPEG's start and end markers with a JFIF header: the colour track's payload."""
_NO_RELEASE = RELEASE_CB(lambda buffer, context: None)


@functools.cache
def _load() -> K4A | str:
    loaded = sdk.load()
    return loaded if isinstance(loaded, str) else K4A(loaded)


def k4a_libraries() -> K4A:
    """The loaded libraries; skips the test (saying why) where pyk4a-bundle's libraries are unavailable."""
    loaded = _load()
    if isinstance(loaded, str):
        pytest.skip(loaded)
    return loaded
