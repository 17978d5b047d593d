"""The source `run` and `record` open: the emulated camera's scene is rendered before streaming starts."""

from __future__ import annotations

import pytest

from tofd.commands.record import _explain_device_drops
from tofd.config import Config
from tofd.service.camera import EMULATED_SERIAL, open_camera


@pytest.mark.slow
def test_emulated_camera_is_fully_rendered_before_its_first_frame():
    with open_camera(Config(), emulate=True) as camera:
        assert camera.emulator.scene.rendered  # the device never waits for the renderer
        assert camera.serial == EMULATED_SERIAL
        frame = next(iter(camera))
        assert frame.ground_truth is not None and frame.device.backend == "emulated"


def test_device_drops_are_explained_in_the_final_line():
    assert _explain_device_drops(0) == ""
    assert "81 frames the camera produced were overwritten" in _explain_device_drops(81)
