"""One opened SR3000-style device: the protocol's control requests and bulk transfers over pyusb."""

from __future__ import annotations

import array
from dataclasses import dataclass

import usb.backend.libusb1
import usb.core
import usb.util

from tofd.drivers.frame import Registers
from tofd.drivers.libusb import bundled_libusb
from tofd.drivers.usb import protocol as p
from tofd.drivers.usb.errors import AccessDenied, DeviceNotFound, UsbCameraError, usb_errors

CONTROL_TIMEOUT_MS = 1000


def libusb_backend() -> object | None:
    """pyusb's libusb-1.0 backend on libusb-package's library when the system has none (drivers.libusb); None (pyusb's
    own search of the system) otherwise."""
    path = bundled_libusb()
    return None if path is None else usb.backend.libusb1.get_backend(find_library=lambda _name: path)


def find_usb_devices(backend: object | None = None) -> list[usb.core.Device]:
    """Every attached device with the protocol's idVendor:idProduct (libusb_backend() unless a backend is given)."""
    with usb_errors("enumerating USB devices"):
        return list(usb.core.find(find_all=True, idVendor=p.VENDOR_ID, idProduct=p.PRODUCT_ID,
                                  backend=libusb_backend() if backend is None else backend))


def registers_from_bank(bank: bytes) -> Registers:
    """The named registers of a READ_REGS(0, 64) answer."""
    return Registers(
        int_time_code=bank[p.Register.INT_TIME], mod_freq_index=bank[p.Register.MOD_FREQ],
        acq_mode=bank[p.Register.ACQ_MODE], data_source=bank[p.Register.DATA_SOURCE],
        amp_threshold=bank[p.Register.AMP_THR_LO] | bank[p.Register.AMP_THR_HI] << 8)


class Sr3000Device:
    """An opened device with GET_INFO read; with claim=True also in configuration 1 with interface 0 claimed
    (needed for frames and bulk writes; control requests alone work without). Close with close()."""

    def __init__(self, dev: usb.core.Device, claim: bool = True) -> None:
        self.dev = dev
        self.bus: int | None = dev.bus
        self.address: int | None = dev.address
        try:
            if claim:
                with usb_errors(f"opening the camera at bus {self.bus} address {self.address}"):
                    self._configure()
                    usb.util.claim_interface(dev, p.INTERFACE)
            self.info = self.get_info()
        except Exception:
            self.close()
            raise

    def _configure(self) -> None:
        """Select configuration 1 unless the OS already did (setting it again would reset the device)."""
        try:
            active = self.dev.get_active_configuration().bConfigurationValue
        except (usb.core.USBError, NotImplementedError):
            active = None
        if active != p.CONFIGURATION:
            self.dev.set_configuration(p.CONFIGURATION)

    @property
    def serial(self) -> str:
        return self.info.serial_str

    def _control_in(self, request: p.Request, value: int, length: int, what: str) -> bytes:
        with usb_errors(what):
            data = self.dev.ctrl_transfer(p.REQUEST_TYPE_IN, request, value, 0, length, CONTROL_TIMEOUT_MS)
        return bytes(data)

    def _control_out(self, request: p.Request, value: int, index: int, what: str) -> None:
        with usb_errors(what):
            self.dev.ctrl_transfer(p.REQUEST_TYPE_OUT, request, value, index, None, CONTROL_TIMEOUT_MS)

    def get_info(self) -> p.InfoBlock:
        return p.InfoBlock.unpack(self._control_in(p.Request.GET_INFO, 0, p.INFO_STRUCT.size, "GET_INFO"))

    def get_status(self) -> p.StatusBlock:
        return p.StatusBlock.unpack(self._control_in(p.Request.GET_STATUS, 0, p.STATUS_STRUCT.size, "GET_STATUS"))

    def read_registers(self, first: int = 0, count: int = p.REGISTER_COUNT) -> bytes:
        data = self._control_in(p.Request.READ_REGS, first, count, f"READ_REGS 0x{first:02X}+{count}")
        if len(data) != count:
            raise UsbCameraError(f"READ_REGS 0x{first:02X}+{count}: device returned {len(data)} bytes")
        return data

    def registers(self) -> Registers:
        return registers_from_bank(self.read_registers())

    def write_register(self, register: int, value: int, via: str = "control") -> None:
        """WRITE_REG as a control request (via="control") or a 2-byte bulk OUT write (via="bulk")."""
        why = p.register_write_error(register, value)
        if why is not None:
            raise ValueError(why)
        what = f"writing 0x{value:02X} to register 0x{register:02X} ({via})"
        if via == "control":
            self._control_out(p.Request.WRITE_REG, register, value, what)
        elif via == "bulk":
            with usb_errors(what):
                self.dev.write(p.EP_OUT, bytes([register, value]), CONTROL_TIMEOUT_MS)
        else:
            raise ValueError(f"via: expected 'control' or 'bulk', got {via!r}")

    def acquire(self, mode: p.AcquireMode) -> None:
        self._control_out(p.Request.ACQUIRE, int(mode), 0, f"ACQUIRE {p.AcquireMode(mode).name}")

    def read_transfer(self, buffer: array.array, timeout_ms: int) -> int:
        """One bulk IN transfer from 0x86 into `buffer`; returns the bytes received."""
        with usb_errors("reading a frame"):
            return self.dev.read(p.EP_IN, buffer, timeout_ms)

    def clear_halt(self, endpoint: int = p.EP_IN) -> None:
        with usb_errors(f"clearing the halt on endpoint 0x{endpoint:02X}"):
            self.dev.clear_halt(endpoint)

    def close(self) -> None:
        """Release the interface and the handle; never raises (the device may be gone or half-dead)."""
        try:
            usb.util.dispose_resources(self.dev)
        except Exception:  # whatever a dying device or backend raises, the handle is abandoned
            pass


@dataclass(frozen=True, slots=True)
class DeviceListing:
    """One attached camera as `tofd devices` shows it; `error` says why it could not be queried."""

    bus: int | None
    address: int | None
    serial: str | None = None  # 8 upper-case hex digits
    firmware: str | None = None  # e.g. "1.0"
    registers: Registers | None = None
    error: str | None = None


def list_devices(backend: object | None = None) -> list[DeviceListing]:
    """Every attached camera with its identity and current registers (an error text where it can't be read)."""
    listings = []
    for dev in find_usb_devices(backend):
        try:
            device = Sr3000Device(dev, claim=False)
            try:
                listings.append(DeviceListing(dev.bus, dev.address, device.serial, device.info.firmware_str,
                                              device.registers()))
            finally:
                device.close()
        except (UsbCameraError, p.ProtocolError) as exc:
            listings.append(DeviceListing(dev.bus, dev.address, error=str(exc)))
    return listings


def open_device(serial: str = "", backend: object | None = None) -> Sr3000Device:
    """Open the camera with this serial (8 hex digits), or the first one that opens if serial is ""."""
    wanted = serial.upper()
    seen: list[str] = []
    denied: AccessDenied | None = None
    for dev in find_usb_devices(backend):
        try:
            device = Sr3000Device(dev)
        except AccessDenied as exc:
            denied = exc
            continue
        except (UsbCameraError, p.ProtocolError) as exc:
            seen.append(f"bus {dev.bus} address {dev.address}: {exc}")
            continue
        if not wanted or device.serial == wanted:
            return device
        seen.append(device.serial)
        device.close()
    if denied is not None:
        raise denied
    target = f"with serial {wanted}" if wanted else f"(USB {p.VENDOR_ID:04x}:{p.PRODUCT_ID:04x})"
    found = f"; found: {', '.join(seen)}" if seen else "; none attached (check the cable and power)"
    raise DeviceNotFound(f"no SR3000-style camera {target}{found}")
