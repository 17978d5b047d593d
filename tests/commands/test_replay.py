"""ReplaySource: lossless and realtime modes, speed, loop, seek, range, EOF, truncated and corrupt files."""

from __future__ import annotations

import logging
import shutil
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from tofd.drivers.frame import Frame
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import ReplaySource
from tofd.drivers.source import DriverError
from tofd_testing.recording_helpers import FRAME_PERIOD_S, assert_frames_equal, write_recording


def collect(source: ReplaySource, timeout_s: float = 20.0, limit: int | None = None,
            each: Callable[[Frame], None] | None = None) -> list[Frame]:
    """Frames of `source` gathered in a thread; fails (instead of hanging) if iteration does not end in time."""
    out: list[Frame] = []
    errors: list[BaseException] = []

    def run() -> None:
        try:
            for frame in source:
                out.append(frame)
                if each is not None:
                    each(frame)
                if limit is not None and len(out) >= limit:
                    source.close()
        except BaseException as exc:  # reported in the test's thread
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        source.close()
        pytest.fail(f"replay did not finish within {timeout_s} s")
    if errors:
        raise errors[0]
    return out


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """20 frames, counters 0..19, 30 fps."""
    path = tmp_path_factory.mktemp("clip") / "clip.mcap"
    return path, write_recording(path, range(20))


def counters(frames: list[Frame]) -> list[int]:
    return [f.frame_counter for f in frames]


def test_lossless_replays_every_frame_then_ends(clip):
    path, frames = clip
    source = ReplaySource(path)
    replayed = collect(source)
    assert counters(replayed) == list(range(20))
    for a, b in zip(frames, replayed, strict=True):
        assert_frames_equal(a, b)
    assert source.stopped_reason == "end"
    assert source.last_good_counter == 19
    assert source.counters["corrupt_tail"] == 0


def test_lossless_never_drops_for_a_slow_consumer(clip):
    path, _ = clip
    source = ReplaySource(path, stop=8)
    replayed = collect(source, each=lambda f: time.sleep(0.05))
    assert counters(replayed) == list(range(8))
    assert source.counters["replay_dropped"] == 0


def test_realtime_follows_recorded_timing(clip):
    path, _ = clip
    source = ReplaySource(path, mode="realtime", stop=10)
    t0 = time.monotonic()
    replayed = collect(source)
    elapsed = time.monotonic() - t0
    assert counters(replayed)[-1] == 9
    assert len(replayed) + source.counters["replay_dropped"] == 10
    assert source.counters["replay_dropped"] <= 2  # a fast consumer misses none (unless the machine stalls)
    assert elapsed >= 9 * FRAME_PERIOD_S * 0.95
    assert elapsed < 9 * FRAME_PERIOD_S + 2.0


def test_realtime_speed_factor(clip):
    path, _ = clip
    t0 = time.monotonic()
    source = ReplaySource(path, mode="realtime", speed=4.0)
    replayed = collect(source)
    elapsed = time.monotonic() - t0
    recorded = 19 * FRAME_PERIOD_S
    assert len(replayed) + source.counters["replay_dropped"] == 20  # drops only if this machine is busy
    assert recorded / 4 * 0.95 <= elapsed < recorded


def test_realtime_skips_and_counts_frames_a_slow_consumer_missed(clip):
    path, _ = clip
    source = ReplaySource(path, mode="realtime")
    replayed = collect(source, each=lambda f: time.sleep(0.1))
    dropped = source.counters["replay_dropped"]
    assert len(replayed) + dropped == 20
    assert dropped >= 8  # 3 frame periods per consumed frame: about 2 of 3 frames are skipped
    assert counters(replayed) == sorted(counters(replayed))
    assert replayed[0].frame_counter == 0 and replayed[-1].frame_counter == 19


def test_loop_repeats_the_range_until_closed(clip):
    path, _ = clip
    source = ReplaySource(path, loop=True, start=5, stop=9)
    replayed = collect(source, limit=10)
    assert counters(replayed) == [5, 6, 7, 8, 5, 6, 7, 8, 5, 6]
    assert source.counters["replay_loops"] == 2


def test_seek_and_range(tmp_path):
    path = tmp_path / "gap.mcap"
    write_recording(path, [*range(10), *range(15, 20)])  # a gap, as after device drops
    assert counters(collect(ReplaySource(path, seek=7))) == [7, 8, 9, 15, 16, 17, 18, 19]
    assert counters(collect(ReplaySource(path, seek=12))) == [15, 16, 17, 18, 19]
    assert counters(collect(ReplaySource(path, start=3, stop=16))) == [*range(3, 10), 15]
    assert counters(collect(ReplaySource(path, seek=30))) == []
    looped = collect(ReplaySource(path, seek=17, start=8, stop=16, loop=True), limit=7)
    assert counters(looped) == [8, 9, 15, 8, 9, 15, 8]  # seek 17 is outside the range: first pass is empty


def test_close_from_another_thread_ends_a_realtime_wait(tmp_path):
    path = tmp_path / "slow.mcap"
    write_recording(path, range(2))
    source = ReplaySource(path, mode="realtime", speed=0.001)  # 33 s between the two frames
    threading.Timer(0.3, source.close).start()
    t0 = time.monotonic()
    assert counters(collect(source, timeout_s=10)) == [0]
    assert time.monotonic() - t0 < 5


@pytest.mark.parametrize("kwargs, match", [
    ({"mode": "fast"}, "mode"), ({"speed": 0}, "speed"), ({"speed": float("nan")}, "speed"),
    ({"start": 5, "stop": 5}, "stop"), ({"seek": -1}, "seek"),
])
def test_bad_arguments_name_themselves(clip, kwargs, match):
    with pytest.raises(ValueError, match=match):
        ReplaySource(clip[0], **kwargs)


def test_missing_or_foreign_file_is_a_clear_driver_error(tmp_path):
    with pytest.raises(DriverError, match="cannot open recording"):
        ReplaySource(tmp_path / "nope.mcap")
    (tmp_path / "x.mcap").write_bytes(b"hello, world, not mcap")
    with pytest.raises(DriverError, match="not a tofd recording"):
        ReplaySource(tmp_path / "x.mcap")


def chunk_ends(path) -> list[int]:
    """Byte offset where each frame's chunk ends, from MCAP's own index of the complete file."""
    with open(path, "rb") as f:
        indexes = make_reader(f).get_summary().chunk_indexes
    return [c.chunk_start_offset + c.chunk_length for c in indexes]


def test_truncated_file_replays_its_prefix_and_says_where_it_stopped(clip, tmp_path, caplog):
    path, frames = clip
    data = path.read_bytes()
    ends = chunk_ends(path)
    (data_end,) = struct.unpack_from("<Q", data, len(data) - 8 - 20)  # footer's summary_start
    rng = np.random.default_rng(0)
    cuts = sorted({8, 20, ends[0] - 1, ends[0], ends[0] + 1, ends[7] + 9, ends[12] - 100, ends[-1],
                   len(data) - 1, *rng.integers(ends[0], len(data), 5).tolist()})
    for cut in cuts:
        cut_path = tmp_path / f"cut{cut}.mcap"
        cut_path.write_bytes(data[:cut])
        source = ReplaySource(cut_path)
        with caplog.at_level(logging.WARNING, logger="tofd.drivers.recording.replay"):
            caplog.clear()
            replayed = collect(source)
        expected = sum(end <= cut for end in ends)
        assert len(replayed) == expected, cut
        for a, b in zip(frames, replayed, strict=False):
            assert_frames_equal(a, b)
        if cut >= data_end:  # cut inside the summary that follows the data: nothing is missing
            assert source.stopped_reason == "end"
            continue
        assert source.stopped_reason == "truncated", (cut, source.stop_detail)
        assert source.counters["corrupt_tail"] == 1
        assert source.last_good_counter == (expected - 1 if expected else None)
        assert "byte" in source.stop_detail
        assert any("readable prefix" in r.message for r in caplog.records)


def test_truncated_file_loops_over_its_prefix(clip, tmp_path):
    path, _ = clip
    cut_path = tmp_path / "cut.mcap"
    shutil.copy(path, cut_path)
    with open(cut_path, "r+b") as f:
        f.truncate(chunk_ends(path)[2] + 5)
    source = ReplaySource(cut_path, loop=True)
    assert counters(collect(source, limit=7)) == [0, 1, 2, 0, 1, 2, 0]
    assert source.counters["corrupt_tail"] == 1


def test_bundled_recording_is_a_complete_face_clip_from_035_to_070_m():
    path = Path(__file__).resolve().parents[2] / "replay_data" / "emulated_face_035_070.mcap"
    assert path.stat().st_size <= 10_000_000
    info = read_recording_info(path)
    assert info.device.backend == "emulated" and info.frame_count >= 100
    source = ReplaySource(path)
    frames = collect(source)
    assert source.stopped_reason == "end" and len(frames) == info.frame_count
    assert all(f.ground_truth is not None for f in frames)
    ranges = [float(np.linalg.norm(f.ground_truth.nose_xyz_m)) for f in frames]
    assert abs(ranges[0] - 0.35) < 0.005 and abs(ranges[-1] - 0.70) < 0.005
    # the ground-truth nose pixel sees the nose: the measured range there agrees with the nose's range
    for f, r in zip(frames[::10], ranges[::10], strict=True):
        u, v = (round(c) for c in f.ground_truth.nose_px)
        assert abs(f.range_m[v, u] - r) < 0.03


def test_damaged_header_gives_a_driver_error_or_the_info_never_another_exception(clip, tmp_path):
    path, _ = clip
    data = path.read_bytes()
    first_chunk = chunk_ends(path)[0] - 1000
    rng = np.random.default_rng(2)
    outcomes = set()
    for pos in rng.integers(0, 3000, 150).tolist():  # the header, metadata and config attachment
        flipped = bytearray(data)
        flipped[pos] ^= 1 << int(rng.integers(8))
        flip_path = tmp_path / "hdr.mcap"
        flip_path.write_bytes(flipped)
        try:
            read_recording_info(flip_path)
            outcomes.add("ok")
        except DriverError:
            outcomes.add("error")
    assert outcomes == {"ok", "error"}
    assert first_chunk > 3000  # the flips stayed in front of the first frame
