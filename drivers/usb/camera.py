"""UsbCamera: a FrameSource reading an SR3000-style camera over pyusb and surviving the protocol's faults.

Faults are counted in `counters` (a collections.Counter) under these keys:

| key | event | what the camera did |
|---|---|---|
| timeout | a bulk read timed out | retried |
| stall | no frame for stall_report_s seconds (once per episode) | logged a warning, kept retrying |
| partial_frame | transfer shorter than 64 + payload_len | dropped it |
| crc_error | header or payload CRC mismatch | dropped it |
| bad_header | wrong magic, version or geometry | dropped it |
| endpoint_stall | pipe error on 0x86 | cleared the halt |
| overflow, io_error | other transfer errors | retried |
| device_dropped | frames the device produced but never delivered (counter gaps, dropped_total) | counted |
| counter_reset | the frame counter went backwards without a reconnect | started counting afresh |
| unplug | no-such-device | closed, began reconnecting |
| reopen_after_io_errors | 5 unexplained transfer errors in a row (also counted as io_error) | as for unplug |
| reconnect_attempt, reconnect | tries to reopen / successful reopen of the same serial | restored registers |
| frames | frames delivered to the consumer | |

Gaps in the stream (a stall, a reconnect) are reported as FrameGap records, once the first frame after
the gap has arrived: appended to `gaps` and passed to the `on_gap` callback (called on the reading thread).
"""

from __future__ import annotations

import array
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from tofd.drivers import sr3000
from tofd.drivers.frame import DEFAULT_REGISTER_VALUES, DeviceInfo, Frame, GroundTruth, Registers
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import FrameSource, StallWatch
from tofd.drivers.usb import protocol as p
from tofd.drivers.usb.device import DeviceListing, list_devices, open_device
from tofd.drivers.usb.errors import (
    DeviceGone,
    EndpointStalled,
    TransferOverflow,
    TransferTimeout,
    UsbCameraError,
)

__all__ = ["DeviceListing", "FrameGap", "UsbCamera", "list_devices"]

log = logging.getLogger(__name__)

IO_ERRORS_BEFORE_REOPEN = 5


@dataclass(frozen=True, slots=True)
class FrameGap:
    """A stretch of time without frames: kind "stall" (reads timing out) or "reconnect" (unplugged)."""

    kind: str
    start_monotonic_s: float  # host time of the last frame before the gap (or of acquisition start)
    end_monotonic_s: float  # host time of the first frame after it
    last_counter: int | None  # frame counter before the gap (None if no frame yet)
    next_counter: int  # frame counter after it (may restart from 0 after a reconnect)


class _DropTally:
    """Frames the device dropped within one acquisition session (one opening of the device).

    Two measures of the same thing: gaps in frame_counter (less the frames the host itself discarded as
    partial or corrupt) and the rise of dropped_total. The tally is the larger of the two cumulative sums,
    which is right whether a device reports its drops by one, the other or both.
    """

    def __init__(self, dropped_at_start: int | None) -> None:
        self.base_dropped = dropped_at_start
        self.last_counter: int | None = None
        self.by_counter = 0
        self.by_total = 0
        self.discarded = 0  # frames the host dropped since the last good frame

    @property
    def total(self) -> int:
        return max(self.by_counter, self.by_total)

    def good_frame(self, header: p.FrameHeader) -> bool:
        """Account one good frame; False if its counter went backwards (the caller starts a new tally)."""
        if self.base_dropped is None:
            self.base_dropped = header.dropped_total
        if self.last_counter is not None:
            if header.frame_counter <= self.last_counter:
                return False
            self.by_counter += max(header.frame_counter - self.last_counter - 1 - self.discarded, 0)
        self.by_total = max(self.by_total, header.dropped_total - self.base_dropped)
        self.last_counter = header.frame_counter
        self.discarded = 0
        return True


class UsbCamera(FrameSource):
    """An SR3000-style camera (protocol of docs/protocol.md) as a stream of Frames.

    Keyword names match tofd's [camera] config section (tofd.service.camera.sr3000_keywords picks them out of it).
    serial: 8 hex digits, "" = the first camera found (then that camera's serial is kept for reconnects).
    int_time_code, mod_freq_index: INT_TIME and MOD_FREQ registers, written and read back at open and
    after every reconnect. read_timeout_s: one bulk read's timeout. stall_report_s: no frame for this long
    is reported (warning, counters["stall"]). reconnect_initial_s / reconnect_max_s: exponential backoff
    between attempts to reopen an unplugged camera. backend: a pyusb backend (None = libusb; the emulator's
    EmulatorBackend in tests). ground_truth: frame_counter -> GroundTruth for scene frames (the emulator's).
    Raises DeviceNotFound / AccessDenied (with the udev rule to install) if the camera can't be opened.
    """

    def __init__(self, serial: str = "", int_time_code: int = DEFAULT_REGISTER_VALUES.int_time_code,
                 mod_freq_index: int = DEFAULT_REGISTER_VALUES.mod_freq_index,
                 read_timeout_s: float = 0.5, stall_report_s: float = 2.0, reconnect_initial_s: float = 0.1,
                 reconnect_max_s: float = 5.0, *, backend: object | None = None, backend_name: str = "usb",
                 intrinsics: Intrinsics | None = None,
                 ground_truth: Callable[[int], GroundTruth | None] | None = None,
                 on_gap: Callable[[FrameGap], None] | None = None) -> None:
        super().__init__()
        if serial:
            p.parse_serial(serial)
        for name, value, top in (("int_time_code", int_time_code, 255),
                                 ("mod_freq_index", mod_freq_index, len(sr3000.MOD_FREQS_MHZ) - 1)):
            if not 0 <= value <= top:
                raise ValueError(f"{name}: expected 0..{top}, got {value}")
        if read_timeout_s < 0.001:
            raise ValueError(f"read_timeout_s: expected >= 0.001 s, got {read_timeout_s}")
        if not 0 < reconnect_initial_s <= reconnect_max_s:
            raise ValueError(f"reconnect_initial_s, reconnect_max_s: expected 0 < initial <= max, got "
                             f"{reconnect_initial_s}, {reconnect_max_s}")
        self.read_timeout_ms = max(1, round(read_timeout_s * 1000))
        self.stall_report_s = stall_report_s
        self.reconnect_initial_s, self.reconnect_max_s = reconnect_initial_s, reconnect_max_s
        self.backend = backend
        self.backend_name = backend_name
        self.intrinsics: Intrinsics = intrinsics or Intrinsics()
        self.ground_truth = ground_truth
        self.on_gap = on_gap
        self.gaps: deque[FrameGap] = deque(maxlen=1000)
        self.last_header: p.FrameHeader | None = None
        self._applied: dict[int, int] = {p.Register.INT_TIME: int_time_code, p.Register.MOD_FREQ: mod_freq_index}
        self._buffer = array.array("B", bytes(p.READ_BUFFER_LEN))
        self._view = memoryview(self._buffer)
        self._io = threading.RLock()  # one USB conversation at a time; close() may come from another thread
        self._acquiring = False
        self._dropped_before = 0  # device drops of earlier sessions
        self._tally = _DropTally(0)
        self._gap_kind: str | None = None
        self._last_frame_s = time.monotonic()  # host time of the last good frame (or of the first start)
        self._io_errors_in_a_row = 0
        self._device = open_device(serial, backend)
        self.serial = self._device.serial
        self._stalls = StallWatch(self.counters, stall_report_s, f"camera {self.serial}")
        self.device_info = DeviceInfo(self.serial, self._device.info.firmware_str, backend_name)
        self._apply_registers()

    # ----------------------------------------------------------------------------------- registers
    @property
    def registers(self) -> Registers:
        """The camera's current register settings (read from the device)."""
        with self._io:
            return self._device.registers()

    def set_register(self, register: int, value: int, via: str = "control") -> None:
        """Write a register (control request or 2-byte bulk write), verify it by reading back, and keep it
        so that it is restored after a reconnect. ValueError for a write the protocol refuses."""
        why = p.register_write_error(register, value)
        if why is not None:
            raise ValueError(why)
        with self._io:
            self._write_verified(register, value, via)
            self._applied[register] = value
            if register in (p.Register.AMP_THR_LO, p.Register.AMP_THR_HI):
                self._read_amp_threshold()  # not in the frame header: frames from now on carry the new value

    def _write_verified(self, register: int, value: int, via: str = "control") -> None:
        self._device.write_register(register, value, via)
        got = self._device.read_registers(register, 1)[0]
        if got != value:
            raise UsbCameraError(f"register 0x{register:02X}: wrote {value}, read back {got}")

    def _apply_registers(self) -> None:
        with self._io:
            for register, value in self._applied.items():
                self._write_verified(register, value)
            self._header_registers: dict[tuple[int, ...], Registers] = {}
            self._read_amp_threshold()

    def _read_amp_threshold(self) -> None:
        """Read the amplitude threshold (AMP_THR_LO | AMP_THR_HI << 8) back from the device (I/O lock held)."""
        lo, hi = self._device.read_registers(p.Register.AMP_THR_LO, 2)
        self._amp_threshold = lo | hi << 8

    # ----------------------------------------------------------------------------------- streaming
    def _start(self) -> None:
        """Start continuous acquisition and a new drop tally (called with the I/O lock held)."""
        self._device.acquire(p.AcquireMode.CONTINUOUS)
        try:
            dropped_at_start: int | None = self._device.get_status().frames_dropped
        except (UsbCameraError, p.ProtocolError):
            dropped_at_start = None  # then the first frame's dropped_total is the baseline
        self._dropped_before += self._tally.total
        self._tally = _DropTally(dropped_at_start)
        self._acquiring = True
        self._stalls.streaming_started()

    def __iter__(self) -> Iterator[Frame]:
        while not self.closed:
            with self._io:
                if self.closed:
                    return
                try:
                    if not self._acquiring:
                        self._start()
                    n = self._device.read_transfer(self._buffer, self.read_timeout_ms)
                    frame = self._accept(self._view[:n])
                except TransferTimeout:
                    self._timed_out()
                    continue
                except EndpointStalled:
                    self.counters["endpoint_stall"] += 1
                    self._clear_halt()
                    continue
                except DeviceGone:
                    self._reconnect()
                    continue
                except TransferOverflow:
                    self.counters["overflow"] += 1
                    continue
                except (UsbCameraError, p.ProtocolError) as exc:
                    self._io_error(exc)
                    continue
                self._io_errors_in_a_row = 0
            if frame is not None:
                self.counters["frames"] += 1
                yield frame

    def _accept(self, data: memoryview) -> Frame | None:
        """Validate one transfer and make it a Frame; None (and a count) if it is dropped."""
        now_mono, now_wall = time.monotonic(), time.time()
        try:
            header = p.check_frame(data)
        except p.PartialFrame:
            self._discard("partial_frame")
            return None
        except p.CrcError:
            self._discard("crc_error")
            return None
        except p.BadHeader:
            self._discard("bad_header")
            return None
        if not self._tally.good_frame(header):
            self.counters["counter_reset"] += 1
            self._dropped_before += self._tally.total
            self._tally = _DropTally(None)
            self._tally.good_frame(header)
        self.counters["device_dropped"] = self._dropped_before + self._tally.total
        self._end_gap(header.frame_counter, now_mono)
        self.last_header = header
        distance, amplitude = p.split_payload(data[p.HEADER_LEN:p.HEADER_LEN + header.payload_len])
        truth = None
        if self.ground_truth is not None and not header.flags & p.FrameFlags.TEST_PATTERN:
            truth = self.ground_truth(header.frame_counter)
        return Frame(range_m=sr3000.raw_to_range_m(distance, header.mod_freq_khz),
                     amplitude=amplitude.astype(np.float32), frame_counter=header.frame_counter,
                     timestamp_us=header.timestamp_us, host_monotonic_s=now_mono, host_wall_s=now_wall,
                     intrinsics=self.intrinsics, device=self.device_info,
                     registers=self._frame_registers(header), ground_truth=truth)

    def _discard(self, kind: str) -> None:
        self.counters[kind] += 1
        self._tally.discarded += 1

    def _frame_registers(self, header: p.FrameHeader) -> Registers:
        """The Registers a frame was taken with, from its header (one object per distinct setting)."""
        index = sr3000.mod_freq_index(header.mod_freq_khz)
        key = (header.int_time_code, header.mod_freq_khz, header.acq_mode, header.data_source, self._amp_threshold)
        if key not in self._header_registers:
            self._header_registers[key] = Registers(
                int_time_code=header.int_time_code,
                mod_freq_index=index if index is not None else self._applied[p.Register.MOD_FREQ],
                acq_mode=header.acq_mode, data_source=header.data_source, amp_threshold=self._amp_threshold)
        return self._header_registers[key]

    # ------------------------------------------------------------------------------------ faults
    def _timed_out(self) -> None:
        if self._stalls.timed_out():
            self._gap_kind = self._gap_kind or "stall"

    def _clear_halt(self) -> None:
        try:
            self._device.clear_halt(p.EP_IN)
        except DeviceGone:
            self._reconnect()
        except UsbCameraError as exc:
            self._io_error(exc)

    def _io_error(self, exc: Exception) -> None:
        """Count an unexpected error; after IO_ERRORS_BEFORE_REOPEN in a row, reopen the device as if unplugged
        (some hosts report a vanishing device as I/O errors before no-such-device)."""
        self.counters["io_error"] += 1
        self._io_errors_in_a_row += 1
        log.warning("camera %s: %s", self.serial, exc)
        if self._io_errors_in_a_row >= IO_ERRORS_BEFORE_REOPEN:
            self._io_errors_in_a_row = 0
            self._reconnect("reopen_after_io_errors")

    def _end_gap(self, counter: int, now_mono: float) -> None:
        """Report the gap that the frame with this counter ends, if there was one."""
        if self._gap_kind is not None:
            last = self.last_header.frame_counter if self.last_header is not None else None
            gap = FrameGap(self._gap_kind, self._last_frame_s, now_mono, last, counter)
            self.gaps.append(gap)
            if self.on_gap is not None:
                self.on_gap(gap)
        self._gap_kind = None
        self._last_frame_s = now_mono
        self._stalls.frame_arrived(now_mono)

    def _reconnect(self, cause: str = "unplug") -> None:
        """Close, then reopen the same serial with exponential backoff; restore registers, restart acquisition.
        `cause` is the counter to bump: "unplug" or "reopen_after_io_errors"."""
        self.counters[cause] += 1
        self._gap_kind = "reconnect"
        log.warning("camera %s: %s; reconnecting", self.serial, cause.replace("_", " "))
        self._device.close()
        self._acquiring = False
        delay = self.reconnect_initial_s
        while not self._closed.wait(delay):
            self.counters["reconnect_attempt"] += 1
            try:
                device = open_device(self.serial, self.backend)
            except (UsbCameraError, p.ProtocolError):
                delay = min(2 * delay, self.reconnect_max_s)
                continue
            self._device = device
            try:
                self._apply_registers()
                self._start()
            except (UsbCameraError, p.ProtocolError) as exc:
                log.warning("camera %s: reopened but %s; retrying", self.serial, exc)
                device.close()
                self._acquiring = False
                continue
            self.counters["reconnect"] += 1
            log.warning("camera %s: reconnected at bus %s address %s", self.serial, device.bus, device.address)
            return

    def close(self) -> None:
        """Stop acquisition and release the device (safe from another thread; a read ends within its timeout)."""
        if self.closed:
            return
        super().close()
        with self._io:
            if self._acquiring:
                try:
                    self._device.acquire(p.AcquireMode.STOP)
                except UsbCameraError:
                    pass
                self._acquiring = False
            self._device.close()
