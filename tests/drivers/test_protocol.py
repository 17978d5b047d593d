"""tofd.drivers.usb.protocol against the literal values of docs/protocol.md."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from tofd.drivers import sr3000
from tofd.drivers.usb import protocol as p

C = 299_792_458.0


def test_constants_are_the_pages():
    assert (p.VENDOR_ID, p.PRODUCT_ID) == (0x0852, 0x0074)
    assert (p.CONFIGURATION, p.INTERFACE, p.INTERFACE_CLASS, p.EP_OUT, p.EP_IN) == (1, 0, 0xFF, 0x02, 0x86)
    assert (p.REQUEST_TYPE_OUT, p.REQUEST_TYPE_IN) == (0x40, 0xC0)
    assert {r.name: r.value for r in p.Request} == {"GET_INFO": 0x01, "READ_REGS": 0x10, "WRITE_REG": 0x11,
                                                     "ACQUIRE": 0x20, "GET_STATUS": 0x21}
    assert {r.name: r.value for r in p.Register} == {"INT_TIME": 1, "MOD_FREQ": 2, "ACQ_MODE": 3, "DATA_SOURCE": 4,
                                                      "AMP_THR_LO": 5, "AMP_THR_HI": 6, "STATUS": 0x3F}
    assert p.HEADER_STRUCT.format == "<4sHHIQHHIBBBBIBBHIII8sI" and p.HEADER_LEN == 64
    assert p.INFO_STRUCT.format == "<4sHHHBBHI14s" and p.INFO_STRUCT.size == 32
    assert p.STATUS_STRUCT.format == "<IIB3x" and p.STATUS_STRUCT.size == 12
    assert p.PAYLOAD_LEN == 101_376
    assert p.READ_BUFFER_LEN == 101_888 and p.READ_BUFFER_LEN % 512 == 0 and p.READ_BUFFER_LEN >= p.FRAME_LEN
    assert [sr3000.mod_freq_khz(i) for i in range(5)] == [40000, 30000, 21000, 20000, 19000]
    assert sr3000.integration_time_us(30) == 6200


def header(**overrides) -> p.FrameHeader:
    fields = dict(frame_counter=7, timestamp_us=123_456_789_012, mod_freq_khz=20000, int_time_code=30,
                  acq_mode=5, data_source=0, dropped_total=3, int_time_us=6200, payload_crc32=0xDEADBEEF)
    return p.FrameHeader(**{**fields, **overrides})


def test_header_bytes_follow_the_table():
    raw = header(flags=1).pack()
    fields = struct.unpack("<4sHHIQHHIBBBBIBBHIII8sI", raw)
    assert fields == (b"SR3F", 1, 64, 7, 123_456_789_012, 176, 144, 20000, 30, 5, 0, 2, 101_376, 1, 0, 1, 3, 6200,
                      0xDEADBEEF, bytes(8), zlib.crc32(raw[:60]))
    assert p.FrameHeader.parse(raw) == header(flags=1)


@pytest.mark.parametrize("offset", [0, 4, 8, 12, 30, 52, 59, 60, 63])
def test_any_flipped_header_byte_is_rejected(offset):
    raw = bytearray(header().pack())
    raw[offset] ^= 0x10
    with pytest.raises((p.CrcError, p.BadHeader)):
        p.FrameHeader.parse(bytes(raw))


def test_bad_magic_geometry_and_short_transfers():
    good = header().pack()
    bad_magic = b"XXXX" + good[4:60]
    with pytest.raises(p.BadHeader, match="magic"):
        p.FrameHeader.parse(bad_magic + struct.pack("<I", zlib.crc32(bad_magic)))
    with pytest.raises(p.BadHeader, match="geometry"):
        p.FrameHeader.parse(header(width=160).pack())
    with pytest.raises(p.BadHeader, match="0 kHz"):
        p.FrameHeader.parse(header(mod_freq_khz=0).pack())
    with pytest.raises(p.PartialFrame):
        p.FrameHeader.parse(good[:40])
    payload = bytes(p.PAYLOAD_LEN)
    frame = header(payload_crc32=zlib.crc32(payload)).pack() + payload
    assert p.check_frame(frame).frame_counter == 7
    with pytest.raises(p.PartialFrame):
        p.check_frame(frame[:-1])
    with pytest.raises(p.CrcError, match="payload"):
        p.check_frame(frame[:-1] + b"\x01")


def test_info_and_status_blocks():
    raw = p.InfoBlock(0x0012ABCD).pack()
    assert struct.unpack("<4sHHHBBHI14s", raw) == (b"SR3K", 1, 176, 144, 64, 2, 0x0100, 0x0012ABCD, bytes(14))
    info = p.InfoBlock.unpack(raw)
    assert (info.serial_str, info.firmware_str) == ("0012ABCD", "1.0")
    with pytest.raises(p.ProtocolError, match="magic"):
        p.InfoBlock.unpack(b"XXXX" + raw[4:])
    with pytest.raises(p.ProtocolError, match="31 bytes"):
        p.InfoBlock.unpack(raw[:31])
    assert p.StatusBlock.unpack(struct.pack("<IIB3x", 10, 2, 2)) == p.StatusBlock(10, 2, 2)


@pytest.mark.parametrize("register, value, refused", [
    (0x01, 255, False), (0x02, 4, False), (0x02, 5, True), (0x3F, 0, True), (0x3E, 7, False), (64, 0, True),
    (0x04, 256, True), (0x05, -1, True)])
def test_register_write_rules(register, value, refused):
    assert (p.register_write_error(register, value) is not None) == refused


def test_distance_conversion():
    raw = np.array([[0, 1, 32767, 65534, 65535]], dtype=np.uint16)
    metres = sr3000.raw_to_range_m(raw, 20000)
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres[0, :4], raw[0, :4] / 65535 * C / (2 * 20e6), rtol=1e-6)
    assert np.isnan(metres[0, 4])
    back = sr3000.range_m_to_raw(metres, 20000)
    np.testing.assert_array_equal(back, raw)
    assert sr3000.range_m_to_raw(np.array([np.nan, 8.0, -0.01]), 20000).tolist() == [0xFFFF, 0xFFFF, 0]


def test_pattern_planes_and_payload_split():
    distance, amplitude = p.pattern_planes()
    assert distance[5, 175] == 65535 and distance[0, 1] == 65535 // 175 and distance[143, 88] == 88 * 65535 // 175
    assert amplitude[143, 0] == 65535 and amplitude[1, 99] == 65535 // 143
    payload = distance.tobytes() + amplitude.tobytes()
    d, a = p.split_payload(payload)
    np.testing.assert_array_equal(d, distance)
    np.testing.assert_array_equal(a, amplitude)
    assert payload[2:4] == (65535 // 175).to_bytes(2, "little")  # row-major, little-endian, distance first
