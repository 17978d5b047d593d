"""The camera a config names, opened for `run` and `record`: the SR3000-style USB camera (or the emulated one,
`--emulate`), or a RealSense, Orbbec or Azure Kinect camera through its vendor's SDK (tofd.drivers.cameras)."""

from __future__ import annotations

import logging
from typing import Any

from tofd.config import CameraConfig, Config
from tofd.drivers.cameras import backend
from tofd.drivers.source import DriverError, FrameSource

EMULATED_SERIAL = "30000001"

log = logging.getLogger(__name__)


def sr3000_keywords(camera: CameraConfig) -> dict[str, Any]:
    """UsbCamera's keywords from the [camera] section (its registers and fault handling)."""
    return {"serial": camera.serial, "int_time_code": camera.int_time_code, "mod_freq_index": camera.mod_freq_index,
            "read_timeout_s": camera.read_timeout_s, "stall_report_s": camera.stall_report_s,
            "reconnect_initial_s": camera.reconnect_initial_s, "reconnect_max_s": camera.reconnect_max_s}


def open_camera(config: Config, emulate: bool) -> FrameSource:
    """The camera of config.camera, streaming, its `intrinsics` set (the device's own calibration for the SDK
    cameras, [intrinsics] for the SR3000); with `emulate` the emulated SR3000 through the same USB code.

    The emulated camera's scene is rendered completely before streaming starts (a few seconds), so the
    device never waits for the renderer and its FIFO does not overflow at the start of a run or recording.
    DriverError (SdkMissing naming the extra for a vendor SDK that is not installed) if it cannot be opened.
    """
    camera = config.camera
    if emulate and camera.kind != "sr3000":
        raise DriverError(f"--emulate emulates the SR3000 camera, not {camera.kind}; a {camera.kind} recording "
                          "runs through its SDK with --playback FILE")
    if camera.kind != "sr3000":
        source = backend(camera.kind).open(camera.request())
        if source.intrinsics is None:
            source.close()
            raise DriverError(f"the {camera.kind} camera gave no calibration")
        return source
    kwargs = sr3000_keywords(camera)
    if emulate:
        from tofd.drivers.emulator.backend import open_emulated_camera

        kwargs["serial"] = camera.serial or EMULATED_SERIAL
        log.info("rendering the emulated camera's scene (a few seconds)")
        return open_emulated_camera(prerender=True, intrinsics=config.intrinsics, **kwargs)
    from tofd.drivers.usb.camera import UsbCamera

    return UsbCamera(**kwargs, intrinsics=config.intrinsics)
