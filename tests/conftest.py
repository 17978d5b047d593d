"""Shared fixtures: emulated SR3000-style cameras reached through the real pyusb code path."""

from __future__ import annotations

import os
import signal

import pytest

from tofd.drivers.emulator.backend import EmulatedCamera, EmulatedSR3000, EmulatorBackend, FaceScene, Motion

# Fast settings for tests: INT_TIME code 0 and a 0.5 ms readout give a frame every 1.3 ms (~770 fps).
FAST_DEVICE = {"readout_s": 0.0005, "fifo_depth": 4}
FAST_CAMERA = {"int_time_code": 0, "read_timeout_s": 0.02, "stall_report_s": 0.1, "reconnect_initial_s": 0.01,
               "reconnect_max_s": 0.05}


def pytest_configure(config: pytest.Config) -> None:
    """Run as if started from a terminal: a shell starts a background job (`bash .ci/run &`) with SIGINT and
    SIGQUIT ignored, tofd keeps a stop signal it was started with ignored (as nohup's SIGHUP), and the tests send
    these to tofd processes they start and to themselves; restored here before any tofd module is imported."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGQUIT) == signal.SIG_IGN:
        signal.signal(signal.SIGQUIT, signal.SIG_DFL)


@pytest.fixture(scope="session", autouse=True)
def render_cache_dir(tmp_path_factory):
    """The emulator's render cache of this session (inherited by the tofd processes tests start), not ~/.cache;
    one for all pytest-xdist workers of the run (entries are written to a temp file and renamed)."""
    base = tmp_path_factory.getbasetemp()
    cache = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "render-cache"
    cache.mkdir(exist_ok=True)
    os.environ["TOFD_CACHE_DIR"] = str(cache)
    return os.environ["TOFD_CACHE_DIR"]


@pytest.fixture(scope="session")
def vendor_cache_dir(request, tmp_path_factory):
    """Where SDK versions the tests install (tofd_testing.vendor_bag_helpers.realsense_env) are kept: pytest's cache,
    across runs; this session's temp dir when pytest runs without its cache plugin (-p no:cacheprovider)."""
    cache = getattr(request.config, "cache", None)
    return cache.mkdir("tofd-realsense") if cache is not None else tmp_path_factory.mktemp("tofd-realsense")


@pytest.fixture(scope="session")
def small_scene() -> FaceScene:
    """A face scene with an 8-pose cycle (renders in a fraction of a second), shared by the session."""
    return FaceScene(motion=Motion(n_poses=8))


@pytest.fixture
def make_emulated_camera(small_scene):
    """Factory: make_emulated_camera(test_pattern=True, device_kwargs..., camera_kwargs...) -> EmulatedCamera.

    The device is `camera.emulator` (inject faults there); every camera is closed at teardown.
    """
    cameras: list[EmulatedCamera] = []

    def make(*, test_pattern: bool = True, serial: str = "30000001", device: dict | None = None,
             **camera_kwargs: object) -> EmulatedCamera:
        emulator = EmulatedSR3000(serial, small_scene, **{**FAST_DEVICE, **(device or {})})
        camera = EmulatedCamera(emulator, **{**FAST_CAMERA, **camera_kwargs})
        cameras.append(camera)
        if test_pattern:
            camera.set_register(0x04, 1)  # DATA_SOURCE = test pattern
        return camera

    yield make
    for camera in cameras:
        camera.close()


@pytest.fixture
def emulated_usb_device():
    """(usb.core.Device, EmulatedSR3000): a raw pyusb device on the emulator backend, for protocol-level tests."""
    import usb.core
    import usb.util

    emulator = EmulatedSR3000("30000001", **FAST_DEVICE)
    dev = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=EmulatorBackend(emulator))
    dev.set_configuration(1)
    usb.util.claim_interface(dev, 0)
    yield dev, emulator
    usb.util.dispose_resources(dev)
