"""RealSense cameras (D400 and others with a depth sensor) through librealsense's pipeline, live or a recording
the SDK plays as its device (`--playback`, rs2::playback in real time).

Streams: Z16 depth and the left infrared imager (Infrared 1, Y8 or Y16) of the depth sensor, in the same mode
(width x height @ fps) validated against the device's stream profiles. The lens is the depth stream's intrinsics
(librealsense's distortion model mapped by tofd.drivers.lens_models); the depth unit is the depth sensor's
(Depth Units option, metres per value); frame numbers and timestamps (milliseconds -> microseconds) are the
device's. Exposure and laser power are set from the request's settings; the sensor's options are read back into
Frame.sensor. An unplug (librealsense's devices-changed callback) raises DeviceLost; the end of a recording
PlaybackEnded.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tofd.drivers.cameras import CameraListing, CameraRequest, PlaybackUnreadable, StreamMode
from tofd.drivers.frame import DeviceInfo, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.lens_models import lens_intrinsics
from tofd.drivers.live import Capture, DeviceLost, PlaybackEnded, SdkCamera
from tofd.drivers.realsense.sdk import rs
from tofd.drivers.source import DriverError

log = logging.getLogger(__name__)

INFRARED_INDEX = 1
"""The infrared stream used as amplitude: the left imager, registered with depth."""
INFRARED_FORMATS = {"y8": 255.0, "y16": 65535.0}
"""Infrared formats tofd takes -> the largest value."""
SETTING_OPTIONS = {"exposure_us": "exposure", "laser_power": "laser_power"}
"""CameraRequest.settings name -> the depth sensor's rs.option it sets (manual exposure turns auto exposure off)."""
REPORTED_OPTIONS = ("exposure", "gain", "enable_auto_exposure", "laser_power", "emitter_enabled", "visual_preset",
                    "depth_units")
"""The depth sensor's options read back into Frame.sensor.settings (those the device has)."""
QUEUE_FRAMES = {"camera": 8, "playback": 64}
"""Framesets librealsense holds for tofd between waits, the oldest dropped beyond (a counter gap): a quarter second
of a camera at 30 fps; two seconds of a recording, so that the service's start-up does not skip its beginning
(tofd's latest-wins queues then drop, and ledger, what the workers cannot take)."""


@dataclass(frozen=True, slots=True, order=True)
class Mode:
    """A depth + infrared stream mode the depth sensor offers."""

    width: int
    height: int
    fps: int
    infrared_format: str  # "y8" or "y16"

    def describe(self) -> str:
        return f"{self.width}x{self.height} @ {self.fps} fps"


def lens_model_name(model: Any) -> str:
    """librealsense's name of an rs.distortion (its rs2_distortion_to_string: brown_conrady -> "Brown Conrady")."""
    return str(model.name).replace("_", " ").title()


def offered_modes(sensor: Any) -> list[Mode]:
    """The modes in which `sensor` streams both Z16 depth and Infrared 1 (Y8 preferred over Y16), in its order."""
    depth: list[tuple[int, int, int]] = []
    infrared: dict[tuple[int, int, int], str] = {}
    for profile in sensor.get_stream_profiles():
        if not profile.is_video_stream_profile():
            continue
        video = profile.as_video_stream_profile()
        key = (video.width(), video.height(), profile.fps())
        if profile.stream_type() == rs.stream.depth and profile.format() == rs.format.z16:
            depth.append(key)
        elif (profile.stream_type() == rs.stream.infrared and profile.stream_index() == INFRARED_INDEX
              and profile.format().name in INFRARED_FORMATS):
            infrared.setdefault(key, profile.format().name)
    modes = [Mode(*key, infrared[key]) for key in depth if key in infrared]
    return list(dict.fromkeys(modes))


def choose_mode(modes: list[Mode], asked: StreamMode, where: str) -> Mode:
    """The first of `modes` matching what is asked (None: any); DriverError listing the modes otherwise."""
    if asked.depth_mode:
        raise DriverError(f"{where}: RealSense cameras have no depth modes (asked for {asked.depth_mode!r}); "
                          "choose the stream by width, height and fps")
    for mode in modes:
        if all(want is None or want == got for want, got in ((asked.width, mode.width), (asked.height, mode.height),
                                                           (asked.fps, mode.fps))):
            return mode
    offered = ", ".join(m.describe() for m in sorted(set(modes), reverse=True)) or "none"
    raise DriverError(f"{where}: no depth + infrared stream of {asked.describe()}; it offers {offered}")


def stream_intrinsics(profile: Any, where: str) -> Intrinsics:
    """The lens of a video stream profile: its intrinsics with librealsense's distortion model mapped."""
    i = profile.as_video_stream_profile().get_intrinsics()
    return lens_intrinsics(i.width, i.height, (i.fx, i.fy, i.ppx, i.ppy), lens_model_name(i.model), list(i.coeffs),
                           where)


def frameset_images(frame: Any) -> tuple[Any, Any] | None:
    """(depth frame, Infrared 1 frame) of a frameset, None when it lacks one."""
    if not frame.is_frameset():
        return None
    frames = frame.as_frameset()
    depth, infrared = frames.get_depth_frame(), frames.get_infrared_frame(INFRARED_INDEX)
    return (depth, infrared) if depth and infrared else None


def capture_of(depth: Any, infrared: Any) -> Capture:
    """The Capture of a depth and an infrared frame: the images copied, the depth frame's number and timestamp
    (milliseconds -> microseconds)."""
    return Capture(depth=np.array(depth.get_data(), copy=True), amplitude=np.array(infrared.get_data(), copy=True),
                   frame_counter=int(depth.get_frame_number()), timestamp_us=round(depth.get_timestamp() * 1000))


def apply_settings(sensor: Any, settings: Mapping[str, float], where: str) -> None:
    """Set the request's settings (SETTING_OPTIONS names, or rs.option names) on a depth sensor, each checked
    against the sensor's range; a manual exposure turns automatic exposure off. DriverError naming the setting."""
    for name, value in settings.items():
        option = getattr(rs.option, SETTING_OPTIONS.get(name, name), None)
        if option is None or not sensor.supports(option):
            raise DriverError(f"{where}: the depth sensor has no {name} setting")
        limits = sensor.get_option_range(option)
        if not limits.min <= value <= limits.max:
            raise DriverError(f"{where}: {name} {value:g} is outside the device's range {limits.min:g}..{limits.max:g}")
        try:
            if name == "exposure_us" and sensor.supports(rs.option.enable_auto_exposure):
                sensor.set_option(rs.option.enable_auto_exposure, 0)
            sensor.set_option(option, value)
        except RuntimeError as exc:  # e.g. a value between the device's steps
            raise DriverError(f"{where}: {name} {value:g}: the device refuses it ({exc})") from None


def sensor_info(sensor: Any, mode: Mode, source: str) -> SensorInfo:
    """The SensorInfo of a depth sensor streaming in `mode`: its depth unit (metres per value), infrared as the
    amplitude, the streams, `source` ("camera" or "playback") and the options of REPORTED_OPTIONS it has."""
    settings = {"source": source, "depth_stream": f"{mode.describe()} Z16",
                "infrared_stream": f"Infrared {INFRARED_INDEX} {mode.describe()} {mode.infrared_format.upper()}"}
    for name in REPORTED_OPTIONS:
        option = getattr(rs.option, name)
        if sensor.supports(option):
            settings[name] = f"{sensor.get_option(option):g}"
    return SensorInfo(depth_unit_m=float(sensor.as_depth_sensor().get_depth_scale()), amplitude="ir",
                      invalid_value=0, amplitude_full_scale=INFRARED_FORMATS[mode.infrared_format],
                      frame_period_s=1.0 / mode.fps, settings=settings)


def device_listing(device: Any) -> CameraListing:
    """A librealsense device as `tofd devices` lists it."""

    def info(field: Any) -> str:
        return str(device.get_info(field)) if device.supports(field) else ""

    usb = info(rs.camera_info.usb_type_descriptor)
    return CameraListing("realsense", info(rs.camera_info.name), info(rs.camera_info.serial_number),
                         info(rs.camera_info.firmware_version), f"USB {usb}" if usb else "")


class RealSenseCamera(SdkCamera):
    """A RealSense camera (request.serial, else the first attached) or a recording (request.playback)."""

    def __init__(self, request: CameraRequest) -> None:
        super().__init__(request)
        self._context = rs.context()
        self._pipeline: Any = None
        self._queue: Any = None
        self._device: Any = None
        self.playback: Any = None  # the rs.playback device of a played recording (pause / resume)
        self._lost = threading.Event()
        self._serial = request.serial
        self._waited = False  # a wait since the streams started (a recording is paused until then)
        self._last_number: int | None = None  # the device's number of the last capture delivered
        if request.playback is None:
            self._context.set_devices_changed_callback(self._devices_changed)

    def _devices_changed(self, event: Any) -> None:
        """librealsense's callback (its own thread): our device removed -> the next wait raises DeviceLost."""
        if self._device is not None and event.was_removed(self._device):
            self._lost.set()

    def _where(self) -> str:
        return (f"RealSense recording {self.request.playback}" if self.request.playback is not None
                else f"RealSense camera {self._serial or '(first attached)'}")

    def _open(self) -> None:
        config = rs.config()
        pipeline = rs.pipeline(self._context)
        if self.request.playback is not None:
            config.enable_device_from_file(str(self.request.playback), repeat_playback=False)
        else:
            self._serial = self._attached_serial()
            config.enable_device(self._serial)
        try:
            device = config.resolve(rs.pipeline_wrapper(pipeline)).get_device()
            sensor = device.first_depth_sensor()
        except RuntimeError as exc:
            if self.request.playback is not None:
                raise PlaybackUnreadable(f"{self._where()}: librealsense cannot play it ({exc})") from None
            raise DriverError(f"{self._where()}: cannot open ({exc})") from None
        mode = choose_mode(offered_modes(sensor), self.request.mode, self._where())
        if self.request.playback is None:
            apply_settings(sensor, self.request.settings, self._where())
        elif self.request.settings:
            log.warning("%s: settings %s are not applied to a recording", self._where(), dict(self.request.settings))
        config.enable_stream(rs.stream.depth, mode.width, mode.height, rs.format.z16, mode.fps)
        config.enable_stream(rs.stream.infrared, INFRARED_INDEX, mode.width, mode.height,
                             getattr(rs.format, mode.infrared_format), mode.fps)
        self._lost.clear()
        self._waited, self._last_number = False, None
        queue = rs.frame_queue(QUEUE_FRAMES["camera" if self.request.playback is None else "playback"],
                               keep_frames=True)
        try:
            profile = pipeline.start(config, queue)
        except RuntimeError as exc:
            raise DriverError(f"{self._where()}: cannot start {mode.describe()} ({exc})") from None
        self._pipeline, self._queue, self._device = pipeline, queue, profile.get_device()
        if self.request.playback is not None:
            self.playback = self._device.as_playback()
            self.playback.set_real_time(True)
            self.playback.pause()  # until the first wait: the consumer sees the recording from its start
        try:
            self._describe(profile, self._device.first_depth_sensor(), mode)
        except DriverError:
            self._stop()
            raise

    def _attached_serial(self) -> str:
        """The serial asked for (or found first) if such a camera is attached; DriverError naming the attached."""
        serials = [str(d.get_info(rs.camera_info.serial_number)) for d in self._context.query_devices()
                   if d.supports(rs.camera_info.serial_number)]
        if self._serial in serials or (serials and not self._serial):
            return self._serial or serials[0]
        which = f" with serial {self._serial}" if self._serial else ""
        raise DriverError(f"no RealSense camera{which} attached (librealsense finds "
                          f"{', '.join(serials) or 'none'}); check the cable, USB 3 port and udev rules")

    def _describe(self, profile: Any, sensor: Any, mode: Mode) -> None:
        """intrinsics, device_info and sensor of the started streams."""
        self.intrinsics = stream_intrinsics(profile.get_stream(rs.stream.depth),
                                            f"{self._where()}: depth stream intrinsics")
        listing = device_listing(self._device)
        self.device_info = DeviceInfo(serial=listing.serial, firmware=listing.firmware, backend="realsense",
                                      model=listing.model or "RealSense")
        self.sensor = sensor_info(sensor, mode, "playback" if self.request.playback is not None else "camera")

    def _wait(self, timeout_s: float) -> Capture | None:
        if self.playback is not None and self.playback.current_status() == rs.playback_status.paused \
                and not self._waited:
            self.playback.resume()
        self._waited = True
        deadline = time.monotonic() + timeout_s
        while (left_ms := int((deadline - time.monotonic()) * 1000)) > 0:
            if self._lost.is_set():
                raise DeviceLost("librealsense reports the device removed")
            ok, frame = self._queue.try_wait_for_frame(left_ms)
            if not ok:
                break
            images = frameset_images(frame)
            if images is None:
                self.counters["unpaired_frame"] += 1
                continue
            capture = capture_of(*images)
            if capture.frame_counter == self._last_number:  # a resumed playback can repeat its current frame
                self.counters["duplicate_frame"] += 1
            else:
                self._last_number = capture.frame_counter
                return capture
        if self.playback is not None and self.playback.current_status() == rs.playback_status.stopped:
            raise PlaybackEnded
        if self._lost.is_set():
            raise DeviceLost("librealsense reports the device removed")
        return None

    def _stop(self) -> None:
        pipeline, self._pipeline, self._queue, self.playback = self._pipeline, None, None, None
        if pipeline is not None:
            try:
                pipeline.stop()
            except RuntimeError as exc:  # never started, or the device is gone
                log.debug("%s: stop: %s", self._where(), exc)


class RealSenseBackend:
    """The `realsense` kind of tofd.drivers.cameras."""

    kind = "realsense"

    def list_cameras(self) -> list[CameraListing]:
        return [device_listing(d) for d in rs.context().query_devices()]

    def open(self, request: CameraRequest) -> RealSenseCamera:
        return RealSenseCamera.opened(request)


BACKEND = RealSenseBackend()
