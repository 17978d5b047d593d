"""`tofd devices` over every camera kind, and a vendor SDK that is missing: the SDKs installed here are listed
with no camera (none is attached), the missing ones name their extra, and `run` / `record` on a kind whose SDK
is missing (blocked as tests/package/test_install.py blocks modules) stop with one line naming the extra, exit 2."""

from __future__ import annotations

import ctypes.util
import importlib

import pytest

from tests.commands.test_cli import one_line_error, tofd
from tests.package.test_install import BLOCKER, COMMAND, run_blocked
from tofd.drivers.cameras import EXTRAS, SDK_KINDS, SdkMissing, backend


def installed(kind: str) -> bool:
    try:
        backend(kind)
    except SdkMissing:
        return False
    return True


def test_devices_lists_each_installed_sdk_with_no_camera_and_names_the_missing_ones_extras():
    assert installed("realsense")  # the test extra installs pyrealsense2 and libusb-package
    proc = tofd("devices")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("sr3000 (SR3000-style USB cameras, 0852:0074)")
    for kind in SDK_KINDS:
        if installed(kind):
            at = lines.index(f"{kind}:")
            assert lines[at + 1] == "  none attached", proc.stdout
        else:
            (line,) = [line for line in lines if line.startswith(f"{kind}: not installed")]
            assert line.endswith(f"pip install 'tofd[{EXTRAS[kind]}]'"), line


NO_SYSTEM_LIBUSB = BLOCKER + """
import ctypes.util
_find_library = ctypes.util.find_library
ctypes.util.find_library = lambda name: None if "usb" in name else _find_library(name)  # no libusb in the system
from tofd.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("blocked", [(), ("libusb_package",)])
def test_on_a_system_without_libusb_the_sr3000_is_looked_for_through_libusb_package(blocked):
    """pip's libusb-package (the service extra) stands in for a system libusb-1.0: the bus is enumerated; without
    either, `devices` says it cannot look and what to install, and still exits 0."""
    proc = run_blocked(NO_SYSTEM_LIBUSB, blocked, "devices")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    at = lines.index("sr3000 (SR3000-style USB cameras, 0852:0074):")
    if blocked:
        assert lines[at + 1].startswith("  cannot look:") and "libusb-1.0" in lines[at + 1], proc.stdout
    else:
        assert lines[at + 1] == "  none attached", proc.stdout


def test_devices_with_the_realsense_sdk_blocked_still_exits_0_naming_its_extra():
    proc = run_blocked(COMMAND, ("pyrealsense2",), "devices", "--emulate")
    assert proc.returncode == 0, proc.stderr
    assert "30000001" in proc.stdout  # the emulated SR3000 as before
    (line,) = [line for line in proc.stdout.splitlines() if line.startswith("realsense:")]
    assert line.startswith("realsense: not installed") and line.endswith("pip install 'tofd[realsense]'"), line


@pytest.mark.parametrize("command", ["run", "record"])
@pytest.mark.parametrize("blocked", ["pyrealsense2", "libusb_package"])
def test_a_missing_sdk_is_one_line_naming_the_extra_exit_2(tmp_path, command, blocked):
    """pyrealsense2 absent, or present without a libusb-1.0 to load (libusb-package blocked on a system without its
    own copy)."""
    if blocked == "libusb_package" and importlib.util.find_spec("libusb_package") is None:
        pytest.skip("libusb-package is not installed")
    if blocked == "libusb_package" and ctypes.util.find_library("usb-1.0") is not None:
        pytest.skip("the system has its own libusb-1.0 (e.g. with Chromium): blocking libusb-package leaves it")
    out = [str(tmp_path / "rec.mcap")] if command == "record" else ["--health-port", "0"]
    proc = run_blocked(COMMAND, (blocked,), command, "--camera", "realsense", *out)
    err = one_line_error(proc, 2, f"tofd {command}: the realsense camera needs its SDK",
                         "pip install 'tofd[realsense]'")
    assert ("libusb-1.0" in err) == (blocked == "libusb_package"), err
    assert not (tmp_path / "rec.mcap").exists()


@pytest.mark.parametrize("command", ["run", "record"])
def test_a_file_the_sdk_cannot_play_is_one_line_exit_2_and_no_camera_one_line_exit_1(tmp_path, command):
    """A --playback file librealsense cannot read is a data error (exit 2); no such camera attached (none is
    here) is a runtime failure (exit 1); both name what they looked for, and no recording is started."""
    bad = tmp_path / "not_a_recording.db3"
    bad.write_bytes(b"SQLite format 3\x00" + b"\x00" * 200)
    out = [str(tmp_path / "rec.mcap")] if command == "record" else ["--health-port", "0"]
    one_line_error(tofd(command, "--camera", "realsense", "--playback", str(bad), *out), 2, str(bad),
                   "librealsense cannot play it")
    one_line_error(tofd(command, "--camera", "realsense", "--serial", "123622270224", *out), 1,
                   "no RealSense camera with serial 123622270224 attached")
    assert not (tmp_path / "rec.mcap").exists()
