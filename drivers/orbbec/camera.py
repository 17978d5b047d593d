"""Orbbec SDK v2 cameras (Femto Bolt / Mega, Gemini) live, or an Orbbec .bag played by the SDK's PlaybackDevice in
real time through the same code: depth with its IR image as amplitude, the lens from the device's calibration.

The stream mode asked for (width, height, fps) is matched against the depth profiles the device offers; the IR
stream is taken in the same size and rate. Depth values are z-depth in the frame's value scale (millimetres per
unit) and become radial range through the depth profile's lens (tofd.drivers.bags.camera_info maps the SDK's
distortion models). Settings: exposure_us (the depth sensor's exposure property, written as it is: the SDK
states no unit; automatic exposure off) and laser_power (the laser's power level where the device has one, else
laser on (> 0) or off (0)), each checked against the device's range. The context's device-changed
callback tells when the camera is unplugged; the shared loop (tofd.drivers.live) then reconnects. A recording is
held paused from opening until the first frame is asked for, so it plays from its start.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

from tofd.drivers.bags.orbbec import PRECISION_LEVEL_MM, PROPERTY_DEPTH_UNIT_MM, PROPERTY_PRECISION_LEVEL
from tofd.drivers.cameras import CameraListing, CameraRequest, SdkMissing
from tofd.drivers.frame import DeviceInfo, SensorInfo
from tofd.drivers.lens_models import orbbec_lens_intrinsics
from tofd.drivers.live import Capture, DeviceLost, PlaybackEnded, SdkCamera
from tofd.drivers.orbbec import sdk
from tofd.drivers.source import DriverError, FrameSource

PROPERTY_LASER = 3  # OB_PROP_LASER_BOOL
PROPERTY_LASER_POWER_LEVEL = 99  # OB_PROP_LASER_POWER_LEVEL_CONTROL_INT
PROPERTY_DEPTH_AUTO_EXPOSURE = 2016  # OB_PROP_DEPTH_AUTO_EXPOSURE_BOOL
PROPERTY_DEPTH_EXPOSURE = 2017  # OB_PROP_DEPTH_EXPOSURE_INT, microseconds
PROPERTY_DEPTH_GAIN = 2018  # OB_PROP_DEPTH_GAIN_INT
REPORTED: dict[str, tuple[int, str]] = {
    "laser": (PROPERTY_LASER, "bool"),
    "laser_power_level": (PROPERTY_LASER_POWER_LEVEL, "int"),
    "depth_auto_exposure": (PROPERTY_DEPTH_AUTO_EXPOSURE, "bool"),
    "depth_exposure_us": (PROPERTY_DEPTH_EXPOSURE, "int"),
    "depth_gain": (PROPERTY_DEPTH_GAIN, "int"),
    "depth_unit_mm": (PROPERTY_DEPTH_UNIT_MM, "float"),
    "depth_precision_level": (PROPERTY_PRECISION_LEVEL, "int"),
}
"""The device properties a frame's SensorInfo reports (where the device has them): name -> (OBPropertyID, type)."""
SETTINGS = ("exposure_us", "laser_power")
PLAYBACK_SUFFIX = "(Playback)"  # what the SDK appends to a played-back device's name


def _sdk() -> sdk.Sdk:
    try:
        return sdk.load()
    except sdk.OrbbecError as exc:
        raise SdkMissing("orbbec", str(exc)) from None


class OrbbecCamera(SdkCamera):
    """An Orbbec camera (request.serial, or the first attached), or request.playback played by the SDK."""

    def __init__(self, request: CameraRequest) -> None:
        super().__init__(request)
        unknown = sorted(set(request.settings) - set(SETTINGS))
        if unknown:
            raise DriverError(f"orbbec camera: unknown setting(s) {', '.join(unknown)} (known: {', '.join(SETTINGS)})")
        self._sdk = _sdk()
        self._context = self._sdk.call("ob_create_context")
        self._lost = threading.Event()
        self._callback = sdk.DEVICE_CHANGED(self._device_changed)  # kept: the SDK holds only its address
        self._callback_id = self._sdk.call("ob_register_device_changed_callback", self._context, self._callback, None)
        self._device: int | None = None
        self._pipeline: int | None = None
        self._owned: list[tuple[str, int]] = []  # (the SDK's delete function, handle) of profiles and their lists
        self._ir_frame = sdk.FRAME_IR
        self._held = False  # a playback paused between opening and the first wait
        self._serial = ""  # the serial of the camera opened (request.serial, or the first one found)

    # ------------------------------------------------------------------------------------------- opening
    def _open(self) -> None:
        self._lost.clear()
        self._device = self._open_device()
        try:
            self._pipeline = self._sdk.call("ob_create_pipeline_with_device", self._device)
            self._start_streams()
        except DriverError:
            self._stop()
            raise

    def _open_device(self) -> int:
        s, request = self._sdk, self.request
        if request.playback is not None:
            try:
                return int(s.call("ob_create_playback_device", str(request.playback).encode()))
            except sdk.OrbbecError as exc:
                raise DriverError(f"{request.playback}: the Orbbec SDK cannot play it ({exc})") from None
        devices = s.call("ob_query_device_list", self._context)
        try:
            serials = [s.text("ob_device_list_get_device_serial_number", devices, i)
                       for i in range(s.call("ob_device_list_get_count", devices))]
            if not serials:
                raise DriverError("no Orbbec camera is attached (`tofd devices` lists the cameras tofd sees)")
            wanted = request.serial or self._serial  # a reconnect reopens the camera it had
            if wanted and wanted not in serials:
                raise DriverError(f"no Orbbec camera with serial {wanted}; attached: {', '.join(serials)}")
            self._serial = wanted or serials[0]
            return int(s.call("ob_device_list_get_device", devices, serials.index(self._serial)))
        finally:
            s.call("ob_delete_device_list", devices)

    def _profiles(self, sensor_type: int) -> list[sdk.Profile]:
        """The video profiles the pipeline offers for a sensor (handles owned by this camera until _stop)."""
        s = self._sdk
        try:
            handles = s.call("ob_pipeline_get_stream_profile_list", self._pipeline, sensor_type)
        except sdk.OrbbecError:
            return []
        self._owned.append(("ob_delete_stream_profile_list", handles))
        profiles = []
        for i in range(s.call("ob_stream_profile_list_get_count", handles)):
            handle = s.call("ob_stream_profile_list_get_profile", handles, i)
            self._owned.append(("ob_delete_stream_profile", handle))
            profiles.append(sdk.read_profile(s, handle))
        return profiles

    def _start_streams(self) -> None:
        s, mode = self._sdk, self.request.mode
        offered = self._profiles(sdk.SENSOR_DEPTH)
        if not offered:
            raise DriverError("the Orbbec device has no depth stream")
        if mode.depth_mode:
            raise DriverError(f"orbbec camera: depth_mode {mode.depth_mode!r}: Orbbec cameras take their depth mode "
                              "from the width, height and fps asked for; offered: "
                              + "; ".join(p.describe() for p in offered))
        depth = next((p for p in offered if (mode.width or p.width) == p.width
                      and (mode.height or p.height) == p.height and (mode.fps or p.fps) == p.fps), None)
        if depth is None:
            raise DriverError(f"the Orbbec device offers no depth stream of {mode.describe()}; it offers: "
                              + "; ".join(p.describe() for p in offered))
        for sensor_type, frame_type in ((sdk.SENSOR_IR, sdk.FRAME_IR), (sdk.SENSOR_IR_LEFT, sdk.FRAME_IR_LEFT)):
            ir = next((p for p in self._profiles(sensor_type)
                       if (p.width, p.height, p.fps) == (depth.width, depth.height, depth.fps)), None)
            if ir is not None:
                self._ir_frame = frame_type
                break
        else:
            raise DriverError(f"the Orbbec device has no IR stream of {depth.describe()} beside its depth stream: "
                              "tofd needs the IR image as amplitude")
        where = "the Orbbec device's depth profile"
        self.intrinsics = orbbec_lens_intrinsics(depth.width, depth.height, depth.k, depth.distortion_model,
                                                 depth.distortion, where)
        self._apply_settings()
        config = s.call("ob_create_config")
        try:
            for profile in (depth, ir):
                s.call("ob_config_enable_stream_with_stream_profile", config, profile.handle)
            s.call("ob_pipeline_start_with_config", self._pipeline, config)
        finally:
            s.call("ob_delete_config", config)
        if self.request.playback is not None:  # played from its start when the first frame is asked for
            s.call("ob_playback_device_pause", self._device)
            self._held = True
        self.device_info = self._device_info()
        self.sensor = SensorInfo(depth_unit_m=self._depth_unit_mm() * 1e-3, amplitude="ir",
                                 invalid_value=0, amplitude_full_scale=65535.0, frame_period_s=1.0 / depth.fps,
                                 settings={"stream": depth.describe(), "sdk": f"OrbbecSDK {s.version}",
                                           "playback": str(self.request.playback or ""), **self._reported()})

    def _device_info(self) -> DeviceInfo:
        s = self._sdk
        info = s.call("ob_device_get_device_info", self._device)
        try:
            name = s.text("ob_device_info_get_name", info)
            while name.endswith(PLAYBACK_SUFFIX):
                name = name[: -len(PLAYBACK_SUFFIX)]
            return DeviceInfo(serial=s.text("ob_device_info_get_serial_number", info), backend="orbbec",
                              model=name or "Orbbec", firmware=s.text("ob_device_info_get_firmware_version", info))
        finally:
            s.call("ob_delete_device_info", info)

    # ------------------------------------------------------------------------------ properties, settings
    def _supported(self, property_id: int, permission: int = sdk.PERMISSION_READ) -> bool:
        try:
            return bool(self._sdk.call("ob_device_is_property_supported", self._device, property_id, permission))
        except sdk.OrbbecError:
            return False

    def _reported(self) -> dict[str, str]:
        """The REPORTED properties the device has, as text."""
        values: dict[str, str] = {}
        for name, (property_id, kind) in REPORTED.items():
            if self._supported(property_id):
                try:
                    values[name] = str(self._sdk.call(f"ob_device_get_{kind}_property", self._device, property_id))
                except sdk.OrbbecError:
                    continue
        return values

    def _depth_unit_mm(self) -> float:
        """Millimetres per depth value as the device states it (its first frames' value scale replaces it)."""
        s = self._sdk
        if self._supported(PROPERTY_DEPTH_UNIT_MM):
            return float(s.call("ob_device_get_float_property", self._device, PROPERTY_DEPTH_UNIT_MM))
        if self._supported(PROPERTY_PRECISION_LEVEL):
            level = s.call("ob_device_get_int_property", self._device, PROPERTY_PRECISION_LEVEL)
            if 0 <= level < len(PRECISION_LEVEL_MM):
                return PRECISION_LEVEL_MM[level]
        return 1.0

    def _apply_settings(self) -> None:
        settings = self.request.settings
        setters: list[tuple[int, str, float]] = []
        if "exposure_us" in settings:
            setters += [(PROPERTY_DEPTH_AUTO_EXPOSURE, "bool", 0), (PROPERTY_DEPTH_EXPOSURE, "int",
                                                                    settings["exposure_us"])]
        if "laser_power" in settings:
            power = settings["laser_power"]
            setters.append((PROPERTY_LASER_POWER_LEVEL, "int", power) if self._supported(PROPERTY_LASER_POWER_LEVEL, 2)
                           else (PROPERTY_LASER, "bool", power > 0))
        for property_id, kind, value in setters:
            if not self._supported(property_id, 2):  # OB_PERMISSION_WRITE
                raise DriverError(f"orbbec camera {self._device_info().model}: cannot set property {property_id} "
                                  f"(for {', '.join(settings)}): the device does not offer it")
            if kind == "int":
                limits = self._sdk.call("ob_device_get_int_property_range", self._device, property_id)
                if not limits.min <= value <= limits.max:
                    raise DriverError(f"orbbec camera: {value:g} for property {property_id} (from "
                                      f"{', '.join(settings)}) is outside the device's {limits.min}..{limits.max}")
            cast: Callable[[float], object] = bool if kind == "bool" else int
            self._sdk.call(f"ob_device_set_{kind}_property", self._device, property_id, cast(value))

    # --------------------------------------------------------------------------------------- streaming
    def _wait(self, timeout_s: float) -> Capture | None:
        s = self._sdk
        if self._held:
            self._held = False
            s.call("ob_playback_device_resume", self._device)
        deadline = time.monotonic() + timeout_s
        while (left_ms := round((deadline - time.monotonic()) * 1000)) > 0:
            if self._lost.is_set():
                raise DeviceLost("the Orbbec SDK reports the camera removed")
            try:
                frameset = s.call("ob_pipeline_wait_for_frameset", self._pipeline, left_ms)
            except sdk.OrbbecError as exc:
                raise DeviceLost(str(exc)) from None
            if not frameset:
                break
            try:
                depth = sdk.frame_data(s, frameset, sdk.FRAME_DEPTH)
                ir = sdk.frame_data(s, frameset, self._ir_frame)
            finally:
                s.call("ob_delete_frame", frameset)
            if depth is None or ir is None:  # a frameset of one stream: its partner was lost
                self.counters["unpaired_range" if ir is None else "unpaired_amplitude"] += 1
                continue
            self._follow_value_scale(depth.value_scale)
            return Capture(depth=depth.image, amplitude=ir.image, frame_counter=depth.index,
                           timestamp_us=depth.timestamp_us)
        if self.request.playback is not None and sdk.PLAYBACK_STATUS.get(
                s.call("ob_playback_device_get_current_playback_status", self._device)) == "stopped":
            raise PlaybackEnded()
        return None

    def _follow_value_scale(self, millimetres: float) -> None:
        """The depth unit a frame states (millimetres per value) becomes the sensor's when it differs."""
        if self.sensor is not None and millimetres > 0 and millimetres * 1e-3 != self.sensor.depth_unit_m:
            self.sensor = dataclasses.replace(self.sensor, depth_unit_m=millimetres * 1e-3)

    def _device_changed(self, removed: int | None, added: int | None, _user: int | None) -> None:
        """The SDK's device-changed callback (its thread): flags the loss of this camera; frees the lists."""
        s = self._sdk
        try:
            if removed:
                gone = {s.text("ob_device_list_get_device_serial_number", removed, i)
                        for i in range(s.call("ob_device_list_get_count", removed))}
                if self.device_info.serial in gone:
                    self._lost.set()
        finally:
            for handle in (removed, added):
                if handle:
                    s.call("ob_delete_device_list", handle)

    def pause_playback(self) -> None:
        """Pause the SDK's playback (a played-back recording only): the stream stops as an unplugged one would."""
        self._sdk.call("ob_playback_device_pause", self._device)

    def resume_playback(self) -> None:
        self._sdk.call("ob_playback_device_resume", self._device)

    def _stop(self) -> None:
        s = self._sdk
        for name, attr in (("ob_pipeline_stop", "_pipeline"), ("ob_delete_pipeline", "_pipeline")):
            if getattr(self, attr) is not None:
                try:
                    s.call(name, getattr(self, attr))
                except sdk.OrbbecError:
                    pass  # a vanished device's pipeline may refuse to stop
        self._pipeline = None
        while self._owned:
            name, handle = self._owned.pop()
            s.call(name, handle)
        if self._device is not None:
            s.call("ob_delete_device", self._device)
            self._device = None

    def close(self) -> None:
        super().close()
        if self._context is not None:
            self._sdk.call("ob_unregister_device_changed_callback", self._context, self._callback_id)
            self._sdk.call("ob_delete_context", self._context)
            self._context = None


@dataclasses.dataclass(frozen=True)
class OrbbecBackend:
    """The Orbbec SDK v2 backend (tofd.drivers.cameras' registry takes its BACKEND)."""

    kind: str = "orbbec"
    extra: str = "orbbec"

    def list_cameras(self) -> list[CameraListing]:
        s = _sdk()
        context = s.call("ob_create_context")
        try:
            devices = s.call("ob_query_device_list", context)
            try:
                return [self._listing(s, devices, i) for i in range(s.call("ob_device_list_get_count", devices))]
            finally:
                s.call("ob_delete_device_list", devices)
        finally:
            s.call("ob_delete_context", context)

    @staticmethod
    def _listing(s: sdk.Sdk, devices: int, index: int) -> CameraListing:
        name = s.text("ob_device_list_get_device_name", devices, index)
        serial = s.text("ob_device_list_get_device_serial_number", devices, index)
        try:
            device = s.call("ob_device_list_get_device", devices, index)
        except sdk.OrbbecError as exc:
            return CameraListing("orbbec", name, serial, detail=f"cannot be opened: {exc}")
        try:
            info = s.call("ob_device_get_device_info", device)
            firmware = s.text("ob_device_info_get_firmware_version", info)
            connection = s.text("ob_device_info_get_connection_type", info)
            s.call("ob_delete_device_info", info)
        finally:
            s.call("ob_delete_device", device)
        return CameraListing("orbbec", name, serial, firmware, connection)

    def open(self, request: CameraRequest) -> FrameSource:
        return OrbbecCamera.opened(request)


BACKEND = OrbbecBackend()
