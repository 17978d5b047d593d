"""Frames and recordings for the recording/replay tests (imported by test_recording.py and test_replay.py)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np

from tofd.drivers import sr3000
from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, Registers
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.reader import ZSTD_FIELD, RecordingReader
from tofd.drivers.recording.replay import iter_frames
from tofd.drivers.recording.writer import RecordingWriter

DEVICE = DeviceInfo(serial="0A1B2C3D", firmware="1.0", backend="emulated")
FRAME_PERIOD_S = 1 / 30
DEFAULT_REGISTERS = Registers()
DEFAULT_INTRINSICS = Intrinsics()


def make_frame(counter: int, *, quantized: bool = True, registers: Registers = DEFAULT_REGISTERS,
               intrinsics: Intrinsics = DEFAULT_INTRINSICS, t0: float = 1000.0) -> Frame:
    """A frame like the USB backend delivers (quantized=True: range and amplitude from uint16 raw values via
    tofd.drivers.usb.protocol) or arbitrary float32 planes (quantized=False, with NaN, -0.0 and inf), 30 fps timing,
    and ground truth on every frame but each 5th (none) and 7th (not visible, no 3-D point)."""
    rng = np.random.default_rng(counter)
    shape = intrinsics.shape
    if quantized:
        v, u = np.indices(shape)
        raw = (3000 + 20 * u + 10 * v + rng.integers(0, 64, size=shape)).astype(np.uint16)  # a noisy slope
        raw[:10, :20] = sr3000.RAW_INVALID
        range_m = sr3000.raw_to_range_m(raw, sr3000.mod_freq_khz(registers.mod_freq_index))
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
                 "registers", "ground_truth", "sensor"):
        assert getattr(a, name) == getattr(b, name), name


# ---------------------------------------------------------------- damage, for test_replay_damage and bench/chaos.py
# These edit a recording as bytes and find frames only through the reader (RecordingReader.frames and its
# offset), so they do not depend on how a frame message is encoded.

def frame_spans(path: Path) -> list[tuple[int, int, int]]:
    """(frame_counter, start, end) per frame record: `end` is where the record holding the frame ends, `start`
    where the previous frame's record ended (so the span may begin with the previous record's index)."""
    spans, start = [], None
    with RecordingReader(path) as reader:
        for item in reader.frames():
            if isinstance(item, Frame):
                spans.append((item.frame_counter, reader.offset if start is None else start, reader.offset))
                start = reader.offset
    return spans


def damage_frame(data: bytearray, span: tuple[int, int, int]) -> None:
    """Flip one byte inside a frame's record (in its compressed planes), so its CRC fails."""
    _, start, end = span
    data[end - (end - start) // 3] ^= 0xFF


def zero_frame_crc(data: bytearray, span: tuple[int, int, int]) -> None:
    """Set the CRC field of the chunk record holding a frame to 0 (MCAP's "no CRC"): the frame stays readable
    but unchecked, so the reader must refuse it."""
    _, start, end = span
    at = bytes(data[start:end]).index(ZSTD_FIELD) + start  # the chunk's compression field
    data[at - 4:at] = b"\0\0\0\0"  # the uncompressed-CRC field just before it


def duplicate_frame(data: bytes, span: tuple[int, int, int]) -> bytes:
    """`data` with a frame's span repeated right after it (the same record twice)."""
    _, start, end = span
    return data[:end] + data[start:end] + data[end:]


MUTATIONS = ("bit_flips", "truncation", "inserted_run", "deleted_run", "duplicated_range", "overwritten_run")


def mutate(data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One random mutation of a file (one of MUTATIONS, at a random place and length) and its name."""
    out = bytearray(data)
    n, kind = len(out), MUTATIONS[int(rng.integers(len(MUTATIONS)))]
    at = int(rng.integers(8, n - 1))
    length = int(rng.integers(1, 5000))
    if kind == "bit_flips":
        for pos in rng.integers(0, n, int(rng.integers(1, 20))):
            out[pos] ^= 1 << int(rng.integers(8))
    elif kind == "truncation":
        del out[at:]
    elif kind == "inserted_run":
        out[at:at] = bytes(rng.integers(0, 256, length, dtype=np.uint8))
    elif kind == "deleted_run":
        del out[at:at + length]
    elif kind == "duplicated_range":
        out[at:at] = out[at - min(at, length):at]
    else:
        out[at:at + length] = bytes(rng.integers(0, 256, len(out[at:at + length]), dtype=np.uint8))
    return kind, bytes(out)


SMALL_INTRINSICS = Intrinsics(width=10, height=10, fx=20.0, fy=20.0, cx=4.5, cy=4.5)
RECORDING_FAULTS = {"damaged_frames": "damaged", "zero_crc_frames": "damaged", "duplicated_frames": "duplicate",
                    "malformed_frames": "invalid_frame"}
"""Faults faulty_copy can put into a recording, and the reason class (before ':') each affected frame is
rejected with."""


def faulty_copy(src: Path, dst: Path, fault: str, counters: set[int]) -> Path:
    """`dst`: recording `src` with `fault` (one of RECORDING_FAULTS) done to the frames of `counters` (not the
    first frame, whose span holds the header): a flipped byte, a zeroed chunk CRC, the record twice, or planes
    of 10x10 pixels (rewritten with the RecordingWriter)."""
    if fault == "malformed_frames":
        small = np.ones((10, 10), np.float32)
        return excerpt(src, dst, None, lambda f: f if f.frame_counter not in counters else dataclasses.replace(
            f, range_m=small, amplitude=small, intrinsics=SMALL_INTRINSICS))
    data = src.read_bytes()
    for span in sorted((s for s in frame_spans(src) if s[0] in counters), key=lambda s: -s[1]):  # back to front
        if fault == "duplicated_frames":
            data = duplicate_frame(data, span)
        else:
            edited = bytearray(data)
            (damage_frame if fault == "damaged_frames" else zero_frame_crc)(edited, span)
            data = bytes(edited)
    dst.write_bytes(data)
    return dst


def excerpt(src: Path, dst: Path, stop: int | None, edit: Callable[[Frame], Frame] = lambda f: f) -> Path:
    """`dst`: the frames of recording `src` with counters below `stop` (None: all), each through `edit`,
    recorded anew."""
    with RecordingWriter(dst) as writer:
        for frame in iter_frames(src, stop=stop):
            writer.write(edit(frame))
    return dst
