"""SR3000-style USB protocol, version 1 (docs/protocol.md): the wire's constants and structs (the device model
itself: tofd.drivers.sr3000).

Shared by the USB backend (host side) and the emulated camera (device side), so both speak one definition.
All multi-byte fields are little-endian.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from enum import IntEnum, IntFlag

import numpy as np

from tofd.drivers.errors import TofdError
from tofd.drivers.frame import DEFAULT_REGISTER_VALUES
from tofd.drivers.sr3000 import HEIGHT, MOD_FREQS_MHZ, WIDTH

VENDOR_ID = 0x0852
PRODUCT_ID = 0x0074
CONFIGURATION = 1  # bConfigurationValue
INTERFACE = 0  # bInterfaceNumber, vendor class 0xFF
INTERFACE_CLASS = 0xFF
EP_OUT = 0x02  # bulk OUT: 2-byte register writes
EP_IN = 0x86  # bulk IN: frames
MAX_PACKET = 512  # bytes, USB 2.0 high-speed bulk


class StringIndex(IntEnum):
    """String descriptor indices."""

    MANUFACTURER = 1
    PRODUCT = 2
    SERIAL = 3  # 8 upper-case hex digits


REQUEST_TYPE_OUT = 0x40  # vendor, device, host-to-device
REQUEST_TYPE_IN = 0xC0  # vendor, device, device-to-host


class Request(IntEnum):
    """Vendor control requests (bRequest)."""

    GET_INFO = 0x01  # IN, 32 bytes
    READ_REGS = 0x10  # IN, wValue = first register, wLength = count
    WRITE_REG = 0x11  # OUT, wValue = register, wIndex = value
    ACQUIRE = 0x20  # OUT, wValue = AcquireMode
    GET_STATUS = 0x21  # IN, 12 bytes


class AcquireMode(IntEnum):
    """wValue of ACQUIRE; also the acquisition mode reported by GET_STATUS."""

    STOP = 0
    ONE_FRAME = 1
    CONTINUOUS = 2


class Register(IntEnum):
    """The named registers of the 64 one-byte registers."""

    INT_TIME = 0x01  # integration time code v: (v + 1) * 0.2 ms
    MOD_FREQ = 0x02  # index into MOD_FREQS_MHZ
    ACQ_MODE = 0x03  # bit flags, opaque to the host
    DATA_SOURCE = 0x04  # 0 scene, 1 test pattern
    AMP_THR_LO = 0x05  # amplitude threshold, opaque
    AMP_THR_HI = 0x06
    STATUS = 0x3F  # read-only


REGISTER_COUNT = 64
READ_ONLY_REGISTERS = frozenset({Register.STATUS})
DEFAULT_REGISTERS = {Register.INT_TIME: DEFAULT_REGISTER_VALUES.int_time_code,
                     Register.MOD_FREQ: DEFAULT_REGISTER_VALUES.mod_freq_index,
                     Register.ACQ_MODE: DEFAULT_REGISTER_VALUES.acq_mode}
"""Power-up register bank of the camera (the values of tofd.drivers.frame.Registers' defaults)."""
"""Power-up values of the named registers; every other register powers up as 0."""


def register_write_error(register: int, value: int) -> str | None:
    """Why the device refuses (STALLs) writing `value` to `register`, or None if the write is valid."""
    if not 0 <= register < REGISTER_COUNT:
        return f"register 0x{register:02X} does not exist (0x00..0x{REGISTER_COUNT - 1:02X})"
    if register in READ_ONLY_REGISTERS:
        return f"register 0x{register:02X} ({Register(register).name}) is read-only"
    if not 0 <= value <= 0xFF:
        return f"value {value} of register 0x{register:02X} is not a byte (0..255)"
    if register == Register.MOD_FREQ and value >= len(MOD_FREQS_MHZ):
        return f"MOD_FREQ index {value} out of range (0..{len(MOD_FREQS_MHZ) - 1})"
    return None


class ProtocolError(TofdError, ValueError):
    """Bytes from the device that do not follow the protocol (a runtime failure: exit status 1)."""


class PartialFrame(ProtocolError):
    """A transfer shorter than 64 + payload_len bytes."""


class CrcError(ProtocolError):
    """A header or payload CRC-32 that does not match."""


class BadHeader(ProtocolError):
    """A frame header with a wrong magic, version, length or geometry."""


# ---------------------------------------------------------------------------------------------- GET_INFO
INFO_STRUCT = struct.Struct("<4sHHHBBHI14s")
INFO_MAGIC = b"SR3K"
PROTOCOL_VERSION = 1
PLANES = 2
FIRMWARE_VERSION = 0x0100  # 1.0


@dataclass(frozen=True, slots=True)
class InfoBlock:
    """The 32-byte answer of GET_INFO."""

    serial: int  # uint32; shown as 8 upper-case hex digits
    firmware_version: int = FIRMWARE_VERSION  # 0x0100 = 1.0
    protocol_version: int = PROTOCOL_VERSION
    width: int = WIDTH
    height: int = HEIGHT
    register_count: int = REGISTER_COUNT
    planes: int = PLANES

    @property
    def serial_str(self) -> str:
        return format_serial(self.serial)

    @property
    def firmware_str(self) -> str:
        return f"{self.firmware_version >> 8}.{self.firmware_version & 0xFF}"

    def pack(self) -> bytes:
        return INFO_STRUCT.pack(INFO_MAGIC, self.protocol_version, self.width, self.height,
                                self.register_count, self.planes, self.firmware_version, self.serial, bytes(14))

    @classmethod
    def unpack(cls, data: bytes) -> InfoBlock:
        if len(data) != INFO_STRUCT.size:
            raise ProtocolError(f"GET_INFO returned {len(data)} bytes, expected {INFO_STRUCT.size}")
        magic, version, width, height, nregs, planes, firmware, serial, _ = INFO_STRUCT.unpack(bytes(data))
        if magic != INFO_MAGIC:
            raise ProtocolError(f"GET_INFO magic {magic!r}, expected {INFO_MAGIC!r}")
        if version != PROTOCOL_VERSION:
            raise ProtocolError(f"protocol version {version}, this host speaks {PROTOCOL_VERSION}")
        return cls(serial, firmware, version, width, height, nregs, planes)


def format_serial(serial: int) -> str:
    """uint32 serial -> 8 upper-case hex digits."""
    return f"{serial:08X}"


def parse_serial(text: str) -> int:
    """8 hex digits -> uint32 serial; ValueError naming the text otherwise."""
    if len(text) != 8 or any(c not in "0123456789abcdefABCDEF" for c in text):
        raise ValueError(f"serial {text!r}: expected 8 hex digits")
    return int(text, 16)


# -------------------------------------------------------------------------------------------- GET_STATUS
STATUS_STRUCT = struct.Struct("<IIB3x")


@dataclass(frozen=True, slots=True)
class StatusBlock:
    """The 12-byte answer of GET_STATUS."""

    frames_produced: int
    frames_dropped: int  # by the device (FIFO overrun)
    acq_mode: int  # AcquireMode

    def pack(self) -> bytes:
        return STATUS_STRUCT.pack(self.frames_produced, self.frames_dropped, self.acq_mode)

    @classmethod
    def unpack(cls, data: bytes) -> StatusBlock:
        if len(data) != STATUS_STRUCT.size:
            raise ProtocolError(f"GET_STATUS returned {len(data)} bytes, expected {STATUS_STRUCT.size}")
        return cls(*STATUS_STRUCT.unpack(bytes(data)))


# ---------------------------------------------------------------------------------------------- frames
HEADER_STRUCT = struct.Struct("<4sHHIQHHIBBBBIBBHIII8sI")
HEADER_LEN = HEADER_STRUCT.size  # 64
HEADER_MAGIC = b"SR3F"
HEADER_CRC_SPAN = 60  # header bytes covered by header_crc32
SAMPLE_FORMAT_U16LE = 1
PAYLOAD_LEN = WIDTH * HEIGHT * 2 * PLANES  # 101,376 bytes
FRAME_LEN = HEADER_LEN + PAYLOAD_LEN  # 101,440 bytes
READ_BUFFER_LEN = -(-FRAME_LEN // MAX_PACKET) * MAX_PACKET  # 101,888 bytes: whole packets, >= one frame


class FrameFlags(IntFlag):
    TEST_PATTERN = 1


@dataclass(frozen=True, slots=True)
class FrameHeader:
    """The 64-byte header in front of every frame's payload (fields in the protocol's order)."""

    frame_counter: int  # every frame the sensor produced, delivered or not
    timestamp_us: int  # device clock since power-up, end of exposure
    mod_freq_khz: int
    int_time_code: int
    acq_mode: int
    data_source: int
    dropped_total: int  # frames the device dropped so far
    int_time_us: int
    payload_crc32: int
    flags: int = 0  # FrameFlags
    width: int = WIDTH
    height: int = HEIGHT
    planes: int = PLANES
    payload_len: int = PAYLOAD_LEN
    sample_format: int = SAMPLE_FORMAT_U16LE
    version: int = PROTOCOL_VERSION
    header_len: int = HEADER_LEN

    def pack(self) -> bytes:
        """64 bytes with header_crc32 computed over bytes 0..59."""
        body = HEADER_STRUCT.pack(
            HEADER_MAGIC, self.version, self.header_len, self.frame_counter, self.timestamp_us, self.width,
            self.height, self.mod_freq_khz, self.int_time_code, self.acq_mode, self.data_source, self.planes,
            self.payload_len, self.sample_format, 0, self.flags, self.dropped_total, self.int_time_us,
            self.payload_crc32, bytes(8), 0)
        return body[:HEADER_CRC_SPAN] + struct.pack("<I", zlib.crc32(body[:HEADER_CRC_SPAN]))

    @classmethod
    def parse(cls, data: bytes | memoryview) -> FrameHeader:
        """Header from the first 64 bytes of a transfer; BadHeader, CrcError or PartialFrame if unusable."""
        if len(data) < HEADER_LEN:
            raise PartialFrame(f"transfer of {len(data)} bytes is shorter than the {HEADER_LEN}-byte header")
        (magic, version, header_len, counter, timestamp, width, height, freq, int_code, acq, source, planes,
         payload_len, sample_format, _, flags, dropped, int_us, payload_crc, _, header_crc) = \
            HEADER_STRUCT.unpack_from(data)
        if magic != HEADER_MAGIC:
            raise BadHeader(f"frame magic {bytes(magic)!r}, expected {HEADER_MAGIC!r}")
        if zlib.crc32(data[:HEADER_CRC_SPAN]) != header_crc:
            raise CrcError(f"header CRC mismatch in frame claiming counter {counter}")
        if version != PROTOCOL_VERSION or header_len != HEADER_LEN:
            raise BadHeader(f"frame header version {version} / length {header_len}, expected 1 / 64")
        if freq == 0:
            raise BadHeader(f"frame {counter}: modulation frequency 0 kHz")
        if (width, height, planes, sample_format) != (WIDTH, HEIGHT, PLANES, SAMPLE_FORMAT_U16LE) \
                or payload_len != PAYLOAD_LEN:
            raise BadHeader(f"frame geometry {width}x{height}x{planes} format {sample_format} "
                            f"payload {payload_len} bytes, expected {WIDTH}x{HEIGHT}x{PLANES} format 1 "
                            f"payload {PAYLOAD_LEN} bytes")
        return cls(counter, timestamp, freq, int_code, acq, source, dropped, int_us, payload_crc, flags,
                   width, height, planes, payload_len, sample_format, version, header_len)


def check_frame(data: bytes | memoryview) -> FrameHeader:
    """Validate one whole transfer (header + payload, CRCs) and return its header."""
    header = FrameHeader.parse(data)
    end = HEADER_LEN + header.payload_len
    if len(data) < end:
        raise PartialFrame(f"frame {header.frame_counter}: transfer of {len(data)} bytes, expected {end}")
    if zlib.crc32(data[HEADER_LEN:end]) != header.payload_crc32:
        raise CrcError(f"payload CRC mismatch in frame {header.frame_counter}")
    return header


def split_payload(payload: bytes | memoryview | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Payload -> (distance, amplitude) uint16 (HEIGHT, WIDTH) views, row 0 at the top."""
    planes = np.frombuffer(payload, dtype="<u2", count=PAYLOAD_LEN // 2).reshape(PLANES, HEIGHT, WIDTH)
    return planes[0], planes[1]


def pattern_planes() -> tuple[np.ndarray, np.ndarray]:
    """DATA_SOURCE=1 planes: distance = u*65535//175 (u = column), amplitude = v*65535//143 (v = row)."""
    u = np.arange(WIDTH, dtype=np.int64) * 65535 // (WIDTH - 1)
    v = np.arange(HEIGHT, dtype=np.int64) * 65535 // (HEIGHT - 1)
    distance = np.broadcast_to(u[None, :], (HEIGHT, WIDTH)).astype("<u2")
    amplitude = np.broadcast_to(v[:, None], (HEIGHT, WIDTH)).astype("<u2")
    return distance, amplitude

