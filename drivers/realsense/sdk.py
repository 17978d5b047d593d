"""pyrealsense2, loaded so that it finds libusb: its wheel links libusb-1.0.so.0 without shipping it, so when the
system has none the copy of the libusb-package wheel (the `realsense` extra installs it) is loaded first."""

from __future__ import annotations

import ctypes
import importlib
from types import ModuleType

from tofd.drivers.libusb import bundled_libusb


def load_libusb() -> None:
    """Make libusb-1.0 loadable for pyrealsense2: the system's, else libusb_package's (nothing when neither)."""
    path = bundled_libusb()
    if path is not None:
        ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)


def load() -> ModuleType:
    """The pyrealsense2 module (ImportError when it or its libusb cannot be loaded)."""
    load_libusb()
    return importlib.import_module("pyrealsense2")


rs = load()
"""pyrealsense2 (untyped: its wheel has no type information)."""
