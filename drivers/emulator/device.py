"""An SR3000-style device as a state machine: registers, control requests, the frame FIFO, faults, plugging.

The emulated sensor produces frames on its own clock whether or not the host reads them:
frame period = 4 x integration time (four phase images) + readout_s (default 8.5 ms), so the default
INT_TIME code 30 (6.2 ms) gives 33.3 ms = 30 fps and code 0 gives 107 fps. Produced frames wait in a FIFO
of `fifo_depth` frames; when it is full the newest frame is dropped (frame_counter still advances and
dropped_total rises), which is what a slow host sees as counter gaps. The header's dropped_total is the
device's drop count when that frame was produced.

Faults are injected explicitly and deterministically (see the inject_* methods); `injected` counts each
kind, so a test can compare it with what the host counted. Frame production is lazy (computed from the
clock at each access), so the emulator needs no thread of its own.
"""

from __future__ import annotations

import errno
import threading
import time
import zlib
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass

from tofd.drivers import sr3000
from tofd.drivers.emulator.scene import FaceScene
from tofd.drivers.frame import GroundTruth
from tofd.drivers.usb import protocol as p
from tofd.drivers.usb.errors import libusb_error

READOUT_S = 0.0085
FIFO_DEPTH = 4
_WAIT_SLICE_S = 0.05  # a blocked read re-checks plugging at least this often

def frame_period_s(int_time_code: int, readout_s: float = READOUT_S) -> float:
    """Seconds between frames: four exposures of (code + 1) * 0.2 ms, then the readout."""
    return 4 * sr3000.integration_time_us(int_time_code) * 1e-6 + readout_s


@dataclass(frozen=True, slots=True)
class _Produced:
    """A frame in the FIFO: what the header needs, captured at the end of its exposure."""

    counter: int
    timestamp_us: int
    int_time_code: int
    mod_freq_index: int
    acq_mode: int
    data_source: int
    dropped_total: int


class EmulatedSR3000:
    """One emulated camera. Plug it into an EmulatorBackend; drive faults with the inject_* methods."""

    def __init__(self, serial: int | str = 0x30000001, scene: FaceScene | None = None, *,
                 fifo_depth: int = FIFO_DEPTH, readout_s: float = READOUT_S, bus: int = 1, address: int = 5,
                 access_denied: bool = False, clock: Callable[[], float] = time.monotonic) -> None:
        self.serial = p.parse_serial(serial) if isinstance(serial, str) else int(serial)
        if fifo_depth < 1:
            raise ValueError(f"fifo_depth: expected >= 1, got {fifo_depth}")
        self._scene = scene
        self.fifo_depth = fifo_depth
        self.readout_s = readout_s
        self.bus, self.address = bus, address
        self.access_denied = access_denied
        self.clock = clock
        self.injected: Counter[str] = Counter()
        self.generation = 0  # bumped at every unplug: handles of an older generation are dead
        self.plugged = True
        self._replug_at: float | None = None
        self._cond = threading.Condition(threading.RLock())
        self._read_faults: deque[str] = deque()  # consumed one per bulk read / delivered frame
        self._gap_pending = 0  # counter values to skip at the next production
        self._gap_drops = False
        self._pattern = p.pattern_planes()
        pattern = self._pattern[0].tobytes() + self._pattern[1].tobytes()
        self._pattern_payload = (pattern, zlib.crc32(pattern))
        self._power_up()

    # ------------------------------------------------------------------------------------- state
    def _power_up(self) -> None:
        self.registers = bytearray(p.REGISTER_COUNT)
        for reg, value in p.DEFAULT_REGISTERS.items():
            self.registers[reg] = value
        self.power_up_s = self.clock()
        self.frame_counter = 0  # the next frame's counter
        self.dropped_total = 0
        self.acq_mode = p.AcquireMode.STOP
        self._next_due: float | None = None
        self._paused_until: float | None = None
        self._fifo: deque[_Produced] = deque()
        self._rest = b""  # the unread tail of a frame read with a short buffer
        self.halted: set[int] = set()
        self.configuration = p.CONFIGURATION  # configured at enumeration, as the OS does for one configuration

    @property
    def scene(self) -> FaceScene:
        """The rendered face (created on first use: loading the mesh costs a little)."""
        if self._scene is None:
            self._scene = FaceScene()
        return self._scene

    @property
    def serial_str(self) -> str:
        return p.format_serial(self.serial)

    def period_s(self) -> float:
        return frame_period_s(self.registers[p.Register.INT_TIME], self.readout_s)

    def status(self) -> p.StatusBlock:
        with self._cond:
            self._advance()
            return p.StatusBlock(self.frame_counter, self.dropped_total, self.acq_mode)

    def ground_truth(self, frame_counter: int) -> GroundTruth:
        """The nose tip in the scene frame with this counter (the pose is a function of the counter)."""
        return self.scene.ground_truth(frame_counter)

    # ------------------------------------------------------------------------------------ plugging
    def unplug(self, replug_after_s: float | None = None) -> None:
        """Disappear from the bus; every open handle fails with no-such-device from now on."""
        with self._cond:
            self.plugged = False
            self.generation += 1
            self._replug_at = None if replug_after_s is None else self.clock() + replug_after_s
            self.injected["unplug"] += 1
            self._cond.notify_all()

    def replug(self) -> None:
        """Appear again, powered up afresh: new bus address, counter from 0, registers at their defaults."""
        with self._cond:
            self.address = self.address % 127 + 1
            self._power_up()
            self.plugged = True
            self._replug_at = None
            self._cond.notify_all()

    def check_replug(self) -> None:
        """Replug now if a timed unplug has run out."""
        with self._cond:
            if not self.plugged and self._replug_at is not None and self.clock() >= self._replug_at:
                self.replug()

    def check_alive(self, generation: int) -> None:
        """Raise no-such-device if a handle of this generation no longer reaches the device."""
        self.check_replug()
        if generation != self.generation or not self.plugged:
            raise libusb_error(errno.ENODEV)

    # ------------------------------------------------------------------------------------- faults
    def inject_timeouts(self, n: int = 1) -> None:
        """The next n bulk reads time out (each after the host's timeout); no frame is lost."""
        self._inject("timeout", n)

    def inject_partial_frames(self, n: int = 1) -> None:
        """The next n frames arrive cut short (header and half the payload)."""
        self._inject("partial_frame", n)

    def inject_crc_errors(self, n: int = 1, where: str = "payload") -> None:
        """The next n frames arrive with one payload byte (where="payload") or header byte flipped."""
        if where not in ("payload", "header"):
            raise ValueError(f"where: expected 'payload' or 'header', got {where!r}")
        self._inject(f"{where}_crc", n)

    def inject_stall(self) -> None:
        """The next bulk read STALLs, and endpoint 0x86 stays halted until the host clears it."""
        self._inject("endpoint_stall", 1)

    def inject_io_errors(self, n: int = 1) -> None:
        """The next n bulk reads fail with an I/O error (what some hosts see while a device is dying)."""
        self._inject("io_error", n)

    def _inject(self, kind: str, n: int) -> None:
        with self._cond:
            self._read_faults.extend([kind] * n)
            self.injected[kind] += n

    def inject_counter_gap(self, n: int, dropped: bool = True) -> None:
        """The next produced frame's counter jumps by n; dropped_total rises by n too if `dropped`."""
        with self._cond:
            self._gap_pending += n
            self._gap_drops = dropped
            self.injected["counter_gap"] += n

    def pause(self, seconds: float) -> None:
        """The sensor produces nothing for `seconds` (the host's reads time out meanwhile)."""
        with self._cond:
            self._advance()
            self._paused_until = self.clock() + seconds
            self.injected["pause"] += 1

    # --------------------------------------------------------------------------------- production
    def _advance(self) -> None:
        """Produce every frame that the sensor finished by now (called with the lock held)."""
        if self.acq_mode == p.AcquireMode.STOP or self._next_due is None:
            return
        now = self.clock()
        if self._paused_until is not None:
            if now < self._paused_until:
                return
            self._next_due = max(self._next_due, self._paused_until + self.period_s())
            self._paused_until = None
        period = self.period_s()
        if now < self._next_due:
            return
        n = 1 if self.acq_mode == p.AcquireMode.ONE_FRAME else int((now - self._next_due) // period) + 1
        if self._gap_pending:
            self.frame_counter += self._gap_pending
            self.dropped_total += self._gap_pending if self._gap_drops else 0
            self._gap_pending = 0
        kept = min(n, self.fifo_depth - len(self._fifo))
        regs = self.registers
        for i in range(kept):
            end_of_exposure = self._next_due + i * period - self.readout_s
            self._fifo.append(_Produced(
                self.frame_counter + i, int((end_of_exposure - self.power_up_s) * 1e6), regs[p.Register.INT_TIME],
                regs[p.Register.MOD_FREQ], regs[p.Register.ACQ_MODE], regs[p.Register.DATA_SOURCE],
                self.dropped_total))
        self.frame_counter += n
        self.dropped_total += n - kept
        self._next_due += n * period
        if self.acq_mode == p.AcquireMode.ONE_FRAME:
            self.acq_mode = p.AcquireMode.STOP

    def _transfer(self, frame: _Produced, fault: str | None) -> bytes:
        """Header + payload of a produced frame, damaged as `fault` says."""
        freq = sr3000.mod_freq_khz(frame.mod_freq_index)
        test_pattern = frame.data_source == 1
        payload, crc = self._pattern_payload if test_pattern else self.scene.payload(frame.counter, freq)
        header = p.FrameHeader(
            frame.counter, frame.timestamp_us, freq, frame.int_time_code, frame.acq_mode, frame.data_source,
            frame.dropped_total, sr3000.integration_time_us(frame.int_time_code), crc,
            flags=p.FrameFlags.TEST_PATTERN if test_pattern else 0).pack()
        if fault == "partial_frame":
            return header + payload[: len(payload) // 2]
        if fault == "payload_crc":
            return header + _flip(payload, len(payload) // 3)
        if fault == "header_crc":
            return _flip(header, 8) + payload
        return header + payload

    # ------------------------------------------------------------------------------ host requests
    def control(self, generation: int, request_type: int, request: int, value: int, index: int,
                data: memoryview) -> int:
        """A control transfer; IN data is written into `data`. Returns the bytes transferred."""
        with self._cond:
            self.check_alive(generation)
            self._advance()
            answer = self._control_answer(request_type, request, value, index, len(data))
            if answer is None:
                return len(data)
            n = min(len(answer), len(data))
            data[:n] = answer[:n]
            return n

    def _control_answer(self, request_type: int, request: int, value: int, index: int,
                        length: int) -> bytes | None:
        """The IN data of a request (None for OUT requests); raises a STALL for anything not in the page."""
        if request_type == 0x80 and request == 0x06:  # standard GET_DESCRIPTOR
            return self._descriptor(value >> 8, value & 0xFF, index)
        if request_type == p.REQUEST_TYPE_IN and index == 0:
            if request == p.Request.GET_INFO and value == 0:
                return p.InfoBlock(self.serial).pack()
            if request == p.Request.GET_STATUS and value == 0:
                return p.StatusBlock(self.frame_counter, self.dropped_total, self.acq_mode).pack()
            if request == p.Request.READ_REGS and value + length <= p.REGISTER_COUNT:
                self.registers[p.Register.STATUS] = self._status_register()
                return bytes(self.registers[value:value + length])
        if request_type == p.REQUEST_TYPE_OUT and length == 0:
            if request == p.Request.WRITE_REG:
                self.write_register(value, index)
                return None
            if request == p.Request.ACQUIRE and index == 0 and value in tuple(p.AcquireMode):
                self._acquire(p.AcquireMode(value))
                return None
        raise libusb_error(errno.EPIPE)

    def _status_register(self) -> int:
        """STATUS (read-only, opaque to the host): bit 0 acquiring, bit 1 FIFO not empty, bit 2 EP 0x86 halted."""
        return (self.acq_mode != p.AcquireMode.STOP) | bool(self._fifo) << 1 | (p.EP_IN in self.halted) << 2

    def write_register(self, register: int, value: int) -> None:
        """WRITE_REG: a STALL for the writes the protocol refuses."""
        if p.register_write_error(register, value) is not None:
            raise libusb_error(errno.EPIPE)
        self.registers[register] = value

    def _acquire(self, mode: p.AcquireMode) -> None:
        if mode == p.AcquireMode.STOP:
            self._fifo.clear()
            self._rest = b""
            self._next_due = None
        elif self.acq_mode == p.AcquireMode.STOP:
            self._next_due = self.clock() + self.period_s()
        self.acq_mode = mode

    def _descriptor(self, kind: int, index: int, langid: int) -> bytes:
        strings = {p.StringIndex.MANUFACTURER: "tofd", p.StringIndex.PRODUCT: "SR3000-style TOF camera (emulated)",
                   p.StringIndex.SERIAL: self.serial_str}
        if kind == 3 and index == 0:
            return bytes([4, 3, 0x09, 0x04])  # LANGID table: en-US
        if kind == 3 and index in strings and langid == 0x0409:
            text = strings[p.StringIndex(index)].encode("utf-16-le")
            return bytes([2 + len(text), 3]) + text
        raise libusb_error(errno.EPIPE)

    def bulk_write(self, generation: int, endpoint: int, data: bytes) -> int:
        """A 2-byte [register, value] write to 0x02 is WRITE_REG; anything else STALLs the endpoint."""
        with self._cond:
            self.check_alive(generation)
            if endpoint != p.EP_OUT or endpoint in self.halted:
                raise libusb_error(errno.EPIPE)
            if len(data) != 2 or p.register_write_error(data[0], data[1]) is not None:
                self.halted.add(endpoint)
                raise libusb_error(errno.EPIPE)
            self._advance()
            self.registers[data[0]] = data[1]
            return 2

    def clear_halt(self, generation: int, endpoint: int) -> None:
        with self._cond:
            self.check_alive(generation)
            self.halted.discard(endpoint)

    def bulk_read(self, generation: int, endpoint: int, buffer: memoryview, timeout_ms: int) -> int:
        """One bulk IN transfer from 0x86: blocks until a frame is ready, the timeout, or an unplug."""
        deadline = None if timeout_ms == 0 else self.clock() + timeout_ms / 1000.0
        with self._cond:
            while True:
                self.check_alive(generation)
                if endpoint != p.EP_IN or endpoint in self.halted:
                    raise libusb_error(errno.EPIPE)
                fault = self._read_faults[0] if self._read_faults else None
                if fault == "timeout":
                    self._read_faults.popleft()
                    self._cond.wait(max(0.0, deadline - self.clock()) if deadline else _WAIT_SLICE_S)
                    raise libusb_error(errno.ETIMEDOUT)
                if fault == "io_error":
                    self._read_faults.popleft()
                    raise libusb_error(errno.EIO)
                if fault == "endpoint_stall":
                    self._read_faults.popleft()
                    self.halted.add(endpoint)
                    raise libusb_error(errno.EPIPE)
                self._advance()
                if not self._rest and self._fifo:
                    if fault is not None:
                        self._read_faults.popleft()
                    self._rest = self._transfer(self._fifo.popleft(), fault)
                if self._rest:
                    return self._deliver(buffer)
                now = self.clock()
                if deadline is not None and now >= deadline:
                    raise libusb_error(errno.ETIMEDOUT)
                wake = [_WAIT_SLICE_S] + [t - now for t in (deadline, self._next_due, self._paused_until)
                                          if t is not None]
                self._cond.wait(max(min(wake), 0.0))

    def _deliver(self, buffer: memoryview) -> int:
        """Copy the pending transfer into the host's buffer, as whole 512-byte packets and a short packet."""
        size = len(buffer)
        if size >= len(self._rest):
            n = len(self._rest)
        elif size % p.MAX_PACKET == 0:
            n = size  # the transfer fills the buffer; the frame's tail waits for the next read
        else:
            self._rest = b""  # the buffer ends inside a packet: babble, the frame is lost
            raise libusb_error(errno.EOVERFLOW)
        buffer[:n] = self._rest[:n]
        self._rest = self._rest[n:]
        return n


def _flip(data: bytes, offset: int) -> bytes:
    """`data` with the byte at `offset` inverted."""
    return data[:offset] + bytes([data[offset] ^ 0xFF]) + data[offset + 1:]
