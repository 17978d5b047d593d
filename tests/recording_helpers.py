"""Frames and recordings for the recording/replay tests (imported by test_recording.py and test_replay.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.frame import DeviceInfo, Frame, GroundTruth, Registers
from drivers.intrinsics import Intrinsics
from drivers.recording.writer import RecordingWriter
from drivers.usb import protocol

DEVICE = DeviceInfo(serial="0A1B2C3D", firmware="1.0", backend="emulated")
FRAME_PERIOD_S = 1 / 30
DEFAULT_REGISTERS = Registers()
DEFAULT_INTRINSICS = Intrinsics()


def make_frame(counter: int, *, quantized: bool = True, registers: Registers = DEFAULT_REGISTERS,
               intrinsics: Intrinsics = DEFAULT_INTRINSICS, t0: float = 1000.0) -> Frame:
    """A frame like the USB backend delivers (quantized=True: range and amplitude from uint16 raw values via
    drivers.usb.protocol) or arbitrary float32 planes (quantized=False, with NaN, -0.0 and inf), 30 fps timing,
    and ground truth on every frame but each 5th (none) and 7th (not visible, no 3-D point)."""
    rng = np.random.default_rng(counter)
    shape = intrinsics.shape
    if quantized:
        v, u = np.indices(shape)
        raw = (3000 + 20 * u + 10 * v + rng.integers(0, 64, size=shape)).astype(np.uint16)  # a noisy slope
        raw[:10, :20] = protocol.RAW_INVALID
        range_m = protocol.raw_to_range_m(raw, protocol.mod_freq_khz(registers.mod_freq_index))
        amplitude = (1000 + rng.integers(0, 512, size=shape)).astype(np.float32)
        amplitude[-1, -3:] = [0, 1, 65535]
    else:
        range_m = rng.uniform(0.3, 2.0, size=shape).astype(np.float32)
        range_m[:10, :20] = np.nan
        range_m[0, 30], range_m[0, 31] = -0.0, np.inf
        amplitude = rng.gamma(2.0, 500.0, size=shape).astype(np.float32)
        amplitude[5, 5] = np.nan
    if counter % 5 == 0:
        gt = None
    elif counter % 7 == 0:
        gt = GroundTruth(nose_px=(float(rng.uniform(0, 175)), 71.25), visible=False)
    else:
        gt = GroundTruth(nose_px=(87.5 + counter / 3, 71.5 - counter / 7), visible=True,
                         nose_xyz_m=(0.01 * counter, -0.02, 0.35 + counter / 1000))
    t = counter * FRAME_PERIOD_S
    return Frame(range_m=range_m, amplitude=amplitude, frame_counter=counter,
                 timestamp_us=123_456_789 + round(t * 1e6), host_monotonic_s=t0 + t,
                 host_wall_s=1.7e9 + t0 + t, intrinsics=intrinsics, device=DEVICE, registers=registers,
                 ground_truth=gt)


def write_recording(path: Path, counters: range | list[int], **kwargs: object) -> list[Frame]:
    """Record make_frame(c) for each counter (closed properly); returns the frames written."""
    frames = [make_frame(c, **kwargs) for c in counters]  # type: ignore[arg-type]
    with RecordingWriter(path, config={"camera": {"serial": DEVICE.serial}}) as writer:
        for frame in frames:
            writer.write(frame)
    return frames


def assert_frames_equal(a: Frame, b: Frame) -> None:
    """Every field equal; planes equal bit for bit (NaN, -0.0 and inf included)."""
    for name in ("range_m", "amplitude"):
        pa, pb = getattr(a, name), getattr(b, name)
        assert pb.dtype == np.float32 and pb.shape == pa.shape, name
        assert np.array_equal(pa.view(np.uint32), pb.view(np.uint32)), name
    for name in ("frame_counter", "timestamp_us", "host_monotonic_s", "host_wall_s", "intrinsics", "device",
                 "registers", "ground_truth"):
        assert getattr(a, name) == getattr(b, name), name
