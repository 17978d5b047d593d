"""The USB backend's exceptions and the one place that turns pyusb errors into them."""

from __future__ import annotations

import errno
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

import usb.core

from tofd.drivers.source import DriverError

UDEV_RULE_NAME = "70-tofd-sr3000.rules"
UDEV_RULE = Path(str(resources.files("tofd.defaults").joinpath(UDEV_RULE_NAME)))
"""The udev rule shipped with tofd (config/, installed as tofd.defaults)."""

LIBUSB_ERRORS = {  # errno -> (libusb-1.0 code, message), as pyusb's libusb1 backend raises them
    errno.EIO: (-1, "Input/output error"),
    errno.EINVAL: (-2, "Invalid parameter"),
    errno.EACCES: (-3, "Access denied (insufficient permissions)"),
    errno.ENODEV: (-4, "No such device (it may have been disconnected)"),
    errno.EBUSY: (-6, "Resource busy"),
    errno.ETIMEDOUT: (-7, "Operation timed out"),
    errno.EOVERFLOW: (-8, "Overflow"),
    errno.EPIPE: (-9, "Pipe error"),
}
_LIBUSB_CODES = {code: err for err, (code, _) in LIBUSB_ERRORS.items()}  # for backends that leave errno unset


def libusb_error(code: int) -> usb.core.USBError:
    """The error a libusb-1.0 backend raises for errno `code` (USBTimeoutError for ETIMEDOUT)."""
    libusb_code, text = LIBUSB_ERRORS[code]
    cls = usb.core.USBTimeoutError if code == errno.ETIMEDOUT else usb.core.USBError
    return cls(text, libusb_code, code)


class UsbCameraError(DriverError):
    """A USB camera problem; `where` says which operation failed."""


class NoUsbBackend(UsbCameraError):
    """pyusb finds no USB library (libusb-1.0) to talk to the bus with."""


class DeviceNotFound(UsbCameraError):
    """No SR3000-style camera (0852:0074) attached, or none with the requested serial."""


class AccessDenied(UsbCameraError):
    """The OS refused to open the device (no udev rule installed)."""


class DeviceBusy(UsbCameraError):
    """Another program holds the device's interface."""


class DeviceGone(UsbCameraError):
    """The device was unplugged (no such device)."""


class TransferTimeout(UsbCameraError):
    """A transfer did not complete in time."""


class EndpointStalled(UsbCameraError):
    """The device answered with a STALL (pipe error): a refused request or a halted endpoint."""


class TransferOverflow(UsbCameraError):
    """The device sent more data than the buffer holds."""


def access_denied_hint() -> str:
    """How to let a normal user open the camera."""
    return (f"install the udev rule {UDEV_RULE} (sudo cp {UDEV_RULE} /etc/udev/rules.d/ && "
            "sudo udevadm control --reload-rules && sudo udevadm trigger), make sure you are in group "
            "plugdev, then replug the camera")


_KINDS: dict[int, type[UsbCameraError]] = {
    errno.EACCES: AccessDenied, errno.EPERM: AccessDenied, errno.ENODEV: DeviceGone, errno.EBUSY: DeviceBusy,
    errno.ETIMEDOUT: TransferTimeout, errno.EPIPE: EndpointStalled, errno.EOVERFLOW: TransferOverflow,
}


# last resort for backends that raise USBError with neither errno nor a libusb code: the message
_TEXTS = (("no such device", errno.ENODEV), ("timed out", errno.ETIMEDOUT), ("timeout", errno.ETIMEDOUT),
          ("pipe", errno.EPIPE), ("stall", errno.EPIPE), ("access", errno.EACCES), ("permission", errno.EACCES),
          ("overflow", errno.EOVERFLOW), ("busy", errno.EBUSY))


def _errno(exc: usb.core.USBError) -> int | None:
    if isinstance(exc, usb.core.USBTimeoutError):
        return errno.ETIMEDOUT
    if exc.errno is not None:
        return abs(exc.errno)
    if exc.backend_error_code in _LIBUSB_CODES:
        return _LIBUSB_CODES[exc.backend_error_code]
    text = str(exc.strerror or exc).lower()
    return next((code for needle, code in _TEXTS if needle in text), None)


def translate(exc: usb.core.USBError, where: str) -> UsbCameraError:
    """The package's exception for a pyusb error raised during `where`."""
    kind = _KINDS.get(_errno(exc) or 0, UsbCameraError)
    message = f"{where}: {exc.strerror or exc}"
    if kind is AccessDenied:
        message += f"; {access_denied_hint()}"
    return kind(message)


@contextmanager
def usb_errors(where: str) -> Iterator[None]:
    """Re-raise pyusb errors inside the block as UsbCameraError subclasses (the single translation point)."""
    try:
        yield
    except usb.core.USBError as exc:
        raise translate(exc, where) from exc
    except usb.core.NoBackendError as exc:
        raise NoUsbBackend(f"{where}: no USB backend available; install libusb-1.0 "
                             "(Debian/Ubuntu: sudo apt install libusb-1.0-0)") from exc
