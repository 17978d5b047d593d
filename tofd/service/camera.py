"""The frame source a config names: its USB camera, or the emulated one (`--emulate`), for `run` and `record`."""

from __future__ import annotations

import dataclasses
import logging

from tofd.config import Config
from tofd.drivers.source import FrameSource

EMULATED_SERIAL = "30000001"

log = logging.getLogger(__name__)


def open_camera(config: Config, emulate: bool) -> FrameSource:
    """The camera of config.camera (UsbCamera), or with `emulate` the emulated one through the same USB code.

    The emulated camera's scene is rendered completely before streaming starts (a few seconds), so the
    device never waits for the renderer and its FIFO does not overflow at the start of a run or recording.
    """
    kwargs = dataclasses.asdict(config.camera)
    if emulate:
        from tofd.drivers.emulator.backend import open_emulated_camera

        serial = kwargs.pop("serial") or EMULATED_SERIAL
        log.info("rendering the emulated camera's scene (a few seconds)")
        return open_emulated_camera(serial=serial, prerender=True, intrinsics=config.intrinsics, **kwargs)
    from tofd.drivers.usb.camera import UsbCamera

    return UsbCamera(**kwargs, intrinsics=config.intrinsics)
