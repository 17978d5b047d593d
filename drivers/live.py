"""What every vendor-SDK camera shares as a frame source: the wait loop, stall reports, reconnection after an
unplug, the end of a played-back recording, and the conversion of a z-depth capture to a Frame.

A backend (tofd.drivers.<vendor>.camera) subclasses SdkCamera and implements three calls on its SDK: `_open`
(start streaming; set intrinsics, device and sensor), `_wait` (the next capture, None on a timeout, DeviceLost when
the device vanished, PlaybackEnded at the end of a recording) and `_stop` (release the device).
"""

from __future__ import annotations

import logging
import threading
import time
from abc import abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Self

import numpy as np

from tofd.drivers.cameras import CameraRequest
from tofd.drivers.depth import range_from_depth
from tofd.drivers.frame import COUNTER_LIMIT, DeviceInfo, Frame, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import DriverError, FrameSource, StallWatch

log = logging.getLogger(__name__)


class DeviceLost(DriverError):
    """The camera vanished (unplugged, powered off, its SDK reports it gone): the loop reconnects."""


class PlaybackEnded(Exception):
    """The recording a playback device plays has no more captures: the stream ends."""


@dataclass(frozen=True, slots=True)
class Capture:
    """One capture as an SDK delivers it: z-depth and the registered IR / active-brightness image."""

    depth: np.ndarray  # (H, W) integer depth values in units of depth_unit_m (0 = no return), or float metres
    amplitude: np.ndarray  # (H, W) IR or active brightness, the device's units
    frame_counter: int  # the device's frame number (any non-negative integer; wrapped to 32 bits)
    timestamp_us: int  # device clock, microseconds


class SdkCamera(FrameSource):
    """A vendor SDK's camera, or a recording played by the SDK as its device, as a stream of Frames.

    Faults are counted in `counters` as the pipeline reads them: "timeout" (a wait without a capture), "stall"
    (no capture for request.stall_report_s; reported once per silence), "unplug" and "reconnect" (the device
    vanished, and came back: the pipeline marks a gap in the drop ledger), "reconnect_attempt".
    """

    def __init__(self, request: CameraRequest) -> None:
        super().__init__()
        self.request = request
        self.intrinsics: Intrinsics | None = None  # set by _open from the device's own calibration
        self.device_info = DeviceInfo(serial=request.serial or "?", backend=request.kind, model=request.kind)
        self.sensor: SensorInfo | None = None  # set by _open: depth unit, amplitude kind, the vendor settings
        self._streaming = False
        self._stalls = StallWatch(self.counters, request.stall_report_s, f"{request.kind} camera")
        self._io = threading.Lock()  # one SDK call at a time: the iterating thread's wait, or close()

    # --------------------------------------------------------------------------------- the SDK's part
    @abstractmethod
    def _open(self) -> None:
        """Open the device (request.serial, or request.playback) and start streaming in request.mode;
        set intrinsics, device_info and sensor. DriverError (naming what the device offers) if it can't."""

    @abstractmethod
    def _wait(self, timeout_s: float) -> Capture | None:
        """The next capture, or None when none came within timeout_s; DeviceLost, PlaybackEnded."""

    @abstractmethod
    def _stop(self) -> None:
        """Stop streaming and release the device (idempotent; never raises for a vanished device)."""

    # ------------------------------------------------------------------------------- the shared loop
    @classmethod
    def opened(cls, request: CameraRequest) -> Self:
        """A camera of this class for `request`, streaming; released again if it cannot start."""
        camera = cls(request)
        try:
            camera.start()
        except BaseException:
            camera.close()
            raise
        return camera

    def start(self) -> None:
        """Open and start streaming now (the first iteration does it otherwise): errors surface at open time."""
        if not self._streaming:
            self._open()
            self._streaming = True
            self._stalls.streaming_started()

    def __iter__(self) -> Iterator[Frame]:
        self.start()
        while not self.closed:
            with self._io:
                if self.closed:
                    return
                try:
                    capture = self._wait(self.request.read_timeout_s)
                except PlaybackEnded:
                    return
                except DeviceLost as exc:
                    self._reconnect(exc)
                    continue
            if capture is None:
                self._stalls.timed_out()
                continue
            self._stalls.frame_arrived(time.monotonic())
            self.counters["frames"] += 1
            yield self.frame(capture)

    def frame(self, capture: Capture) -> Frame:
        """The Frame of one capture: z-depth to radial range through the device's lens, IR as amplitude."""
        if self.intrinsics is None or self.sensor is None:
            raise DriverError(f"{self.request.kind} camera: a capture before the camera was opened")
        return Frame(range_m=range_from_depth(capture.depth, self.sensor.depth_unit_m, self.intrinsics),
                     amplitude=capture.amplitude.astype(np.float32),
                     frame_counter=capture.frame_counter % COUNTER_LIMIT,
                     timestamp_us=max(0, int(capture.timestamp_us)), host_monotonic_s=time.monotonic(),
                     host_wall_s=time.time(), intrinsics=self.intrinsics, device=self.device_info, sensor=self.sensor)

    def _reconnect(self, cause: DeviceLost) -> None:
        """Release the device, then reopen it (same serial) with exponential backoff until it is back or closed
        (called with the I/O lock held; close() sets the closed flag first, which ends the backoff)."""
        self.counters["unplug"] += 1
        log.warning("%s camera %s: %s; reconnecting", self.request.kind, self.device_info.serial, cause)
        self._stop()
        self._streaming = False
        delay = self.request.reconnect_initial_s
        while not self._closed.wait(delay):
            self.counters["reconnect_attempt"] += 1
            try:
                self.start()
            except DriverError:
                delay = min(2 * delay, self.request.reconnect_max_s)
                continue
            self.counters["reconnect"] += 1
            log.warning("%s camera %s: reconnected", self.request.kind, self.device_info.serial)
            return

    def close(self) -> None:
        """Stop streaming and release the device (safe from another thread: it waits for the current wait, which
        ends within request.read_timeout_s)."""
        if self.closed:
            return
        super().close()
        with self._io:
            self._stop()
            self._streaming = False
