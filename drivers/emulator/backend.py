"""The emulated SR3000-style camera as a pyusb backend, so the real pyusb code path runs without hardware.

    from tofd.drivers.emulator.backend import EmulatedSR3000, EmulatorBackend
    backend = EmulatorBackend(EmulatedSR3000(serial="30000001"))
    dev = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=backend)   # a real usb.core.Device

`open_emulated_camera()` wires one emulated device into a UsbCamera in one call. The device model
(registers, frame FIFO, faults, unplug/replug) lives in drivers/emulator/device.py, the scene in
drivers/emulator/scene.py.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import usb.backend

from tofd.drivers.emulator.device import EmulatedSR3000
from tofd.drivers.emulator.scene import FaceScene, Motion
from tofd.drivers.usb import protocol as p
from tofd.drivers.usb.camera import UsbCamera
from tofd.drivers.usb.errors import libusb_error

__all__ = ["EmulatedCamera", "EmulatedSR3000", "EmulatorBackend", "FaceScene", "Motion", "open_emulated_camera"]

_SPEED_HIGH = 3  # libusb_speed: USB 2.0 high speed
_BULK = 0x02


@dataclass(frozen=True, slots=True)
class _DeviceId:
    """What enumerate_devices yields: a device as it was plugged (a replug is a new id)."""

    device: EmulatedSR3000
    generation: int


@dataclass(slots=True)
class _Handle:
    device: EmulatedSR3000
    generation: int
    claimed: set[int] = field(default_factory=set)


def _descriptor(**fields: object) -> SimpleNamespace:
    return SimpleNamespace(extra_descriptors=[], **fields)


_CONFIG = _descriptor(bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=1,
                      bConfigurationValue=p.CONFIGURATION, iConfiguration=0, bmAttributes=0x80, bMaxPower=250)
_INTERFACE = _descriptor(bLength=9, bDescriptorType=4, bInterfaceNumber=p.INTERFACE, bAlternateSetting=0,
                         bNumEndpoints=2, bInterfaceClass=p.INTERFACE_CLASS, bInterfaceSubClass=0,
                         bInterfaceProtocol=0, iInterface=0)
_ENDPOINTS = [_descriptor(bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=_BULK,
                          wMaxPacketSize=p.MAX_PACKET, bInterval=0, bRefresh=0, bSynchAddress=0)
              for address in (p.EP_OUT, p.EP_IN)]


class EmulatorBackend(usb.backend.IBackend):
    """A pyusb backend whose bus holds emulated SR3000-style devices (one by default)."""

    def __init__(self, *devices: EmulatedSR3000) -> None:
        super().__init__()
        self.devices = list(devices) or [EmulatedSR3000()]

    # ----------------------------------------------------------------------------- enumeration
    def enumerate_devices(self):
        for device in self.devices:
            device.check_replug()
            if device.plugged:
                yield _DeviceId(device, device.generation)

    def get_parent(self, dev: _DeviceId) -> None:
        return None

    def get_device_descriptor(self, dev: _DeviceId) -> SimpleNamespace:
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0, bDeviceProtocol=0,
            bMaxPacketSize0=64, idVendor=p.VENDOR_ID, idProduct=p.PRODUCT_ID, bcdDevice=p.FIRMWARE_VERSION,
            iManufacturer=p.StringIndex.MANUFACTURER, iProduct=p.StringIndex.PRODUCT,
            iSerialNumber=p.StringIndex.SERIAL, bNumConfigurations=1, bus=dev.device.bus,
            address=dev.device.address, port_number=1, port_numbers=(1,), speed=_SPEED_HIGH)

    def get_configuration_descriptor(self, dev: _DeviceId, config: int) -> SimpleNamespace:
        if config != 0:
            raise IndexError(f"configuration index {config}")
        return _CONFIG

    def get_interface_descriptor(self, dev: _DeviceId, intf: int, alt: int, config: int) -> SimpleNamespace:
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError(f"interface {intf} alternate setting {alt} of configuration {config}")
        return _INTERFACE

    def get_endpoint_descriptor(self, dev: _DeviceId, ep: int, intf: int, alt: int, config: int):
        if (intf, alt, config) != (0, 0, 0) or not 0 <= ep < len(_ENDPOINTS):
            raise IndexError(f"endpoint {ep} of interface {intf}")
        return _ENDPOINTS[ep]

    # ------------------------------------------------------------------------------- handles
    def open_device(self, dev: _DeviceId) -> _Handle:
        dev.device.check_alive(dev.generation)
        if dev.device.access_denied:
            raise libusb_error(errno.EACCES)
        return _Handle(dev.device, dev.generation)

    def close_device(self, dev_handle: _Handle) -> None:
        dev_handle.claimed.clear()

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        dev_handle.device.check_alive(dev_handle.generation)
        if config_value not in (0, p.CONFIGURATION):
            raise libusb_error(errno.EINVAL)
        dev_handle.device.configuration = config_value

    def get_configuration(self, dev_handle: _Handle) -> int:
        dev_handle.device.check_alive(dev_handle.generation)
        return dev_handle.device.configuration

    def set_interface_altsetting(self, dev_handle: _Handle, intf: int, altsetting: int) -> None:
        self._check_interface(dev_handle, intf)
        if altsetting != 0:
            raise libusb_error(errno.EINVAL)

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        self._check_interface(dev_handle, intf)
        dev_handle.claimed.add(intf)

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        dev_handle.device.check_alive(dev_handle.generation)
        dev_handle.claimed.discard(intf)

    def _check_interface(self, dev_handle: _Handle, intf: int) -> None:
        dev_handle.device.check_alive(dev_handle.generation)
        if dev_handle.device.configuration != p.CONFIGURATION or intf != p.INTERFACE:
            raise libusb_error(errno.EINVAL)

    # ------------------------------------------------------------------------------ transfers
    def ctrl_transfer(self, dev_handle: _Handle, bmRequestType: int, bRequest: int, wValue: int, wIndex: int,
                      data, timeout: int) -> int:
        return dev_handle.device.control(dev_handle.generation, bmRequestType, bRequest, wValue, wIndex,
                                         memoryview(data).cast("B"))

    def bulk_write(self, dev_handle: _Handle, ep: int, intf: int, data, timeout: int) -> int:
        self._check_claimed(dev_handle, intf)
        return dev_handle.device.bulk_write(dev_handle.generation, ep, memoryview(data).cast("B").tobytes())

    def bulk_read(self, dev_handle: _Handle, ep: int, intf: int, buff, timeout: int) -> int:
        self._check_claimed(dev_handle, intf)
        return dev_handle.device.bulk_read(dev_handle.generation, ep, memoryview(buff).cast("B"), timeout)

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        dev_handle.device.clear_halt(dev_handle.generation, ep)

    def _check_claimed(self, dev_handle: _Handle, intf: int) -> None:
        dev_handle.device.check_alive(dev_handle.generation)
        if intf not in dev_handle.claimed:
            raise libusb_error(errno.EINVAL)


class EmulatedCamera(UsbCamera):
    """A UsbCamera reading an emulated device through pyusb; `emulator` is the device (inject faults there)."""

    def __init__(self, emulator: EmulatedSR3000, **camera_kwargs: Any) -> None:
        self.emulator = emulator
        self.usb_backend = EmulatorBackend(emulator)
        camera_kwargs.setdefault("serial", emulator.serial_str)
        super().__init__(backend=self.usb_backend, backend_name="emulated",
                         ground_truth=emulator.ground_truth, **camera_kwargs)


def open_emulated_camera(*, serial: str = "30000001", test_pattern: bool = False, scene: FaceScene | None = None,
                         prerender: bool = False, fifo_depth: int = 4, readout_s: float = 0.0085,
                         **camera_kwargs: object) -> EmulatedCamera:
    """One emulated camera behind a UsbCamera, ready to iterate.

    camera_kwargs go to UsbCamera (int_time_code, mod_freq_index, read_timeout_s, ...). test_pattern
    selects DATA_SOURCE=1 (written by the host, so it survives reconnects). prerender=True renders the
    whole pose cycle before returning (about 6 s for the default 240 poses), so the device never waits
    for the renderer; otherwise the cycle renders on a background thread while streaming starts (on a
    busy machine the first cycle may then overrun the FIFO: counted as device_dropped).
    """
    emulator = EmulatedSR3000(serial, scene, fifo_depth=fifo_depth, readout_s=readout_s)
    if not test_pattern:
        emulator.scene.prerender() if prerender else emulator.scene.prerender_in_background()
    camera = EmulatedCamera(emulator, **camera_kwargs)
    if test_pattern:
        camera.set_register(p.Register.DATA_SOURCE, 1)
    return camera
