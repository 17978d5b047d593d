"""Where libusb-1.0 comes from for the USB cameras' libraries (pyusb for the SR3000, librealsense): the system's,
else the copy in the libusb-package wheel (the service and realsense extras install it), so that pip alone reaches
a camera on a machine without the system package."""

from __future__ import annotations

import ctypes.util


def bundled_libusb() -> str | None:
    """The path of libusb-package's libusb-1.0 when the system has none of its own; None when the system has one, or
    libusb-package is not installed or has no copy for this platform (then the system's search decides)."""
    if ctypes.util.find_library("usb-1.0"):
        return None
    try:
        import libusb_package  # type: ignore[import-untyped]
    except ImportError:
        return None
    path = libusb_package.get_library_path()
    return None if path is None else str(path)
