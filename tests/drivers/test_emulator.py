"""The emulated device, spoken to with plain pyusb calls and the literal values of the protocol page."""

from __future__ import annotations

import array
import errno
import struct
import time
import zlib

import numpy as np
import pytest
import usb.core
import usb.util

from tofd.drivers.emulator.backend import EmulatedSR3000, EmulatorBackend
from tofd.drivers.emulator.device import frame_period_s

IN, OUT = 0xC0, 0x40
FRAME = 64 + 101_376
BUFFER = 101_888


def stalls(call):
    with pytest.raises(usb.core.USBError) as info:
        call()
    assert info.value.errno == errno.EPIPE, info.value
    return info.value


def read_frame(dev, size=BUFFER, timeout=1000):
    buf = array.array("B", bytes(size))
    n = dev.read(0x86, buf, timeout)
    return bytes(buf[:n])


def test_descriptors_and_strings(emulated_usb_device):
    dev, _ = emulated_usb_device
    assert (dev.idVendor, dev.idProduct, dev.bus, dev.address) == (0x0852, 0x0074, 1, 5)
    assert dev.serial_number == "30000001" and dev.manufacturer and dev.product
    intf = dev.get_active_configuration()[(0, 0)]
    assert intf.bInterfaceClass == 0xFF and intf.bInterfaceNumber == 0
    assert [(e.bEndpointAddress, e.wMaxPacketSize, usb.util.endpoint_type(e.bmAttributes)) for e in intf] == [
        (0x02, 512, usb.util.ENDPOINT_TYPE_BULK), (0x86, 512, usb.util.ENDPOINT_TYPE_BULK)]


def test_get_info_and_status(emulated_usb_device):
    dev, _ = emulated_usb_device
    info = bytes(dev.ctrl_transfer(IN, 0x01, 0, 0, 32))
    assert struct.unpack("<4sHHHBBHI14s", info) == (b"SR3K", 1, 176, 144, 64, 2, 0x0100, 0x30000001, bytes(14))
    assert struct.unpack("<IIB3x", bytes(dev.ctrl_transfer(IN, 0x21, 0, 0, 12))) == (0, 0, 0)
    dev.ctrl_transfer(OUT, 0x11, 0x01, 0)  # a frame every 1.3 ms
    dev.ctrl_transfer(OUT, 0x20, 2, 0)
    time.sleep(0.02)
    produced, dropped, mode = struct.unpack("<IIB3x", bytes(dev.ctrl_transfer(IN, 0x21, 0, 0, 12)))
    assert mode == 2 and produced >= 5 and dropped == produced - 4  # nobody reads: a 4-frame FIFO overruns
    dev.ctrl_transfer(OUT, 0x20, 0, 0)
    assert bytes(dev.ctrl_transfer(IN, 0x21, 0, 0, 12))[8] == 0


def test_registers_read_write_control_and_bulk(emulated_usb_device):
    dev, emulator = emulated_usb_device
    regs = bytes(dev.ctrl_transfer(IN, 0x10, 0, 0, 64))
    assert (regs[1], regs[2], regs[3], regs[4]) == (30, 3, 0x05, 0)
    dev.ctrl_transfer(OUT, 0x11, 0x01, 12)
    dev.write(0x02, bytes([0x02, 1]))
    dev.write(0x02, bytes([0x20, 0xEE]))
    assert bytes(dev.ctrl_transfer(IN, 0x10, 1, 0, 2)) == bytes([12, 1])
    assert bytes(dev.ctrl_transfer(IN, 0x10, 0x20, 0, 1)) == bytes([0xEE])
    assert emulator.period_s() == pytest.approx(4 * 13 * 0.2e-3 + 0.0005)


@pytest.mark.parametrize("register, value", [(0x3F, 1), (64, 0), (0x01, 256), (0x02, 5)])
def test_refused_writes_stall(emulated_usb_device, register, value):
    dev, emulator = emulated_usb_device
    before = bytes(emulator.registers)
    stalls(lambda: dev.ctrl_transfer(OUT, 0x11, register, value))
    if value <= 255:  # a byte: the same write as a 2-byte bulk OUT STALLs endpoint 0x02 until cleared
        stalls(lambda: dev.write(0x02, bytes([register, value])))
        stalls(lambda: dev.write(0x02, bytes([0x10, 1])))
        dev.clear_halt(0x02)
        dev.write(0x02, bytes([0x10, 1]))
        before = before[:0x10] + b"\x01" + before[0x11:]
    assert bytes(emulator.registers) == before


def test_other_bad_requests_stall(emulated_usb_device):
    dev, _ = emulated_usb_device
    stalls(lambda: dev.ctrl_transfer(IN, 0x99, 0, 0, 4))  # unknown request
    stalls(lambda: dev.ctrl_transfer(IN, 0x01, 1, 0, 32))  # GET_INFO with wValue != 0
    stalls(lambda: dev.ctrl_transfer(OUT, 0x01, 0, 0))  # GET_INFO in the wrong direction
    stalls(lambda: dev.ctrl_transfer(OUT, 0x20, 3, 0))  # ACQUIRE with a bad mode
    stalls(lambda: dev.ctrl_transfer(IN, 0x10, 60, 0, 5))  # READ_REGS past register 63
    stalls(lambda: dev.write(0x02, bytes([1, 2, 3])))  # a bulk OUT that is not 2 bytes
    assert bytes(dev.ctrl_transfer(IN, 0x01, 0, 0, 32))[:4] == b"SR3K"  # the device still answers


def test_frame_transfer_header_payload_and_timing(emulated_usb_device):
    dev, emulator = emulated_usb_device
    dev.ctrl_transfer(OUT, 0x11, 0x04, 1)  # DATA_SOURCE = test pattern
    dev.ctrl_transfer(OUT, 0x11, 0x01, 0)  # INT_TIME code 0: a frame every 4 * 0.2 ms + 0.5 ms readout
    dev.ctrl_transfer(OUT, 0x20, 2, 0)
    frames = [read_frame(dev) for _ in range(3)]
    for raw in frames:
        assert len(raw) == FRAME
        h = struct.unpack("<4sHHIQHHIBBBBIBBHIII8sI", raw[:64])
        assert h[:3] == (b"SR3F", 1, 64) and h[5:8] == (176, 144, 20000) and h[8:13] == (0, 5, 1, 2, 101_376)
        assert h[13:16] == (1, 0, 1) and h[17] == 200 and h[19] == bytes(8)  # format, reserved, flags, int_time_us
        assert h[18] == zlib.crc32(raw[64:]) and h[20] == zlib.crc32(raw[:60])
        planes = np.frombuffer(raw[64:], "<u2").reshape(2, 144, 176)
        assert planes[0, 17, 100] == 100 * 65535 // 175 and planes[1, 100, 17] == 100 * 65535 // 143
    counters = [struct.unpack_from("<I", raw, 8)[0] for raw in frames]
    stamps = [struct.unpack_from("<Q", raw, 12)[0] for raw in frames]
    period_us = frame_period_s(0, 0.0005) * 1e6
    assert np.all(np.diff(counters) >= 1)
    np.testing.assert_allclose(np.diff(stamps) / np.diff(counters), period_us, atol=2)


def test_default_rate_is_30_fps():
    assert 1 / frame_period_s(30) == pytest.approx(30.0, abs=0.05)


def test_one_frame_acquisition(emulated_usb_device):
    dev, _ = emulated_usb_device
    dev.ctrl_transfer(OUT, 0x20, 1, 0)
    assert len(read_frame(dev)) == FRAME
    with pytest.raises(usb.core.USBTimeoutError):
        read_frame(dev, timeout=20)
    assert struct.unpack("<IIB3x", bytes(dev.ctrl_transfer(IN, 0x21, 0, 0, 12))) == (1, 0, 0)


def test_buffer_sizes(emulated_usb_device):
    dev, _ = emulated_usb_device
    dev.ctrl_transfer(OUT, 0x20, 2, 0)
    with pytest.raises(usb.core.USBError) as info:
        read_frame(dev, size=100_000)  # ends inside a packet
    assert info.value.errno == errno.EOVERFLOW
    first = read_frame(dev, size=200 * 512 - 512 * 2)  # whole packets, smaller than a frame
    rest = read_frame(dev)
    assert len(first) == 101_376 and len(first) + len(rest) == FRAME and first[:4] == b"SR3F"
    assert zlib.crc32((first + rest)[64:]) == struct.unpack("<4sHHIQHHIBBBBIBBHIII8sI", first[:64])[18]


def test_unplug_and_replug_at_the_pyusb_level():
    emulator = EmulatedSR3000(readout_s=0.0005)
    backend = EmulatorBackend(emulator)
    dev = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=backend)
    dev.ctrl_transfer(OUT, 0x11, 0x01, 0)
    dev.ctrl_transfer(OUT, 0x20, 2, 0)
    read_frame(dev)
    emulator.unplug(replug_after_s=0.05)
    with pytest.raises(usb.core.USBError) as info:
        read_frame(dev)
    assert info.value.errno == errno.ENODEV
    assert usb.core.find(idVendor=0x0852, backend=backend) is None
    time.sleep(0.06)
    new = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=backend)
    assert new is not None and new.address == 6 and new.serial_number == "30000001"
    with pytest.raises(usb.core.USBError):  # the old handle stays dead
        dev.ctrl_transfer(IN, 0x01, 0, 0, 32)
    regs = bytes(new.ctrl_transfer(IN, 0x10, 0, 0, 5))
    assert regs[1] == 30  # powered up afresh: default registers, counter from 0, not acquiring
    assert struct.unpack("<IIB3x", bytes(new.ctrl_transfer(IN, 0x21, 0, 0, 12))) == (0, 0, 0)
    usb.util.dispose_resources(new)


def test_access_denied_device_still_enumerates():
    backend = EmulatorBackend(EmulatedSR3000(access_denied=True))
    dev = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=backend)
    assert dev.bus == 1
    with pytest.raises(usb.core.USBError) as info:
        dev.ctrl_transfer(IN, 0x01, 0, 0, 32)
    assert info.value.errno == errno.EACCES


def test_scene_is_deterministic_and_prerenders_in_background():
    from tofd.drivers.emulator.backend import FaceScene, Motion

    background = FaceScene(motion=Motion(n_poses=4))
    background.prerender_in_background().join(timeout=30)
    fresh = FaceScene(motion=Motion(n_poses=4))
    for counter in (2, 3, 6):  # counter 6 is pose 2 of the next cycle
        assert background.payload(counter, 20000) == fresh.payload(counter, 20000)
        assert background.ground_truth(counter) == fresh.ground_truth(counter)
    distance = [np.linalg.norm(background.ground_truth(i).nose_xyz_m) for i in range(4)]
    np.testing.assert_allclose([distance[0], distance[2]], [0.35, 0.70], atol=1e-9)  # near and far ends
