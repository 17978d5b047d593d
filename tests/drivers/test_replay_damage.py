"""Damaged recordings: resync after damage, lost/invalid/duplicated frames rejected for the ledger, CRC-less
chunks refused, protected metadata, and a fuzz of the bundled recording."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from tests.commands.test_replay import collect, counters
from tofd.drivers.bags.source import RejectsAfter
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import ReplaySource
from tofd.drivers.recording.writer import RecordingWriter
from tofd.drivers.source import DriverError, Rejected, SourceReport
from tofd_testing.pipeline_sources import dropped_frames
from tofd_testing.recording_helpers import (
    RECORDING_FAULTS,
    SMALL_INTRINSICS,
    assert_frames_equal,
    excerpt,
    faulty_copy,
    make_frame,
    mutate,
    write_recording,
)

BUNDLED = Path(__file__).resolve().parents[2] / "replay_data" / "emulated_face_035_070.mcap"
V1_CLIP = Path(__file__).resolve().parents[1] / "data" / "v1_first3.mcap"
"""The first 3 frames of the bundled clip as it was recorded in format 1 (metadata without CRCs)."""


@pytest.fixture(scope="module")
def clip101(tmp_path_factory):
    """101 frames, counters 0..100, and each frame chunk's (start, end) byte offsets."""
    path = tmp_path_factory.mktemp("clip101") / "clip.mcap"
    frames = write_recording(path, range(101))
    with open(path, "rb") as f:
        chunks = [(c.chunk_start_offset, c.chunk_start_offset + c.chunk_length)
                  for c in make_reader(f).get_summary().chunk_indexes]
    return path, frames, chunks


def replay(path: Path, **kwargs) -> tuple[ReplaySource, list, list]:
    source = ReplaySource(path, **kwargs)
    frames = collect(source)
    return source, frames, source.take_rejected()


def damaged_copy(tmp_path: Path, path: Path, name: str, edit) -> Path:
    data = bytearray(path.read_bytes())
    edit(data)
    out = tmp_path / name
    out.write_bytes(data)
    return out


def test_64_corrupted_bytes_after_frame_38_lose_only_that_frame(clip101, tmp_path):
    path, frames, chunks = clip101

    def corrupt(data):
        start = chunks[39][0] - 24  # the end of frame 38's message indexes and the start of frame 39
        data[start:start + 64] = bytes(np.random.default_rng(0).integers(0, 256, 64, dtype=np.uint8))
    source, replayed, rejected = replay(damaged_copy(tmp_path, path, "d.mcap", corrupt))
    assert counters(replayed) == [c for c in range(101) if c != 39]
    for frame in replayed:
        assert_frames_equal(frames[frame.frame_counter], frame)
    assert [(r.frame_counter, r.reason.split(":")[0]) for r in rejected] == [(39, "damaged")]
    assert source.stopped_reason == "end" and source.counters["damaged"] == 1


def test_a_cut_recording_reports_where_it_stopped_through_the_frame_source_contract(clip101, tmp_path):
    """The report of a truncated file names the last intact frame; RejectsAfter reports its source's and adds the
    earlier stage's rejects after the frames."""
    path, _, chunks = clip101
    cut = damaged_copy(tmp_path, path, "cut.mcap", lambda data: data.__delitem__(slice(chunks[50][1] - 100, None)))
    inner = ReplaySource(cut)
    assert inner.report == SourceReport() and inner.expected_frames is None  # no footer: the count is unknown
    source = RejectsAfter(inner, [Rejected(7000, "damaged: an earlier import's tail")])
    replayed = collect(source)
    report = source.report
    assert report == inner.report and report.stopped_early and report.reason == "truncated"
    assert report.last_good_counter == replayed[-1].frame_counter == 49
    assert report.line().startswith("truncated after frame 49: ")
    assert [r.frame_counter for r in source.take_rejected()][-1] == 7000
    assert source.intrinsics == inner.intrinsics == replayed[0].intrinsics and source.settings == inner.settings


@pytest.mark.parametrize("k", [0, 6, 99])
def test_bit_flip_inside_a_frame_rejects_that_frame_and_replays_the_rest(clip101, tmp_path, k):
    path, frames, chunks = clip101

    def flip(data):
        data[chunks[k][1] - 1000] ^= 0x10  # inside frame k's compressed planes
    source, replayed, rejected = replay(damaged_copy(tmp_path, path, "f.mcap", flip))
    assert counters(replayed) == [c for c in range(101) if c != k]
    if k == 0:  # nothing before it: the loss cannot be counted, but it is counted as uncounted damage
        assert rejected == [] and source.counters["damaged_uncounted"] == 1
    else:
        reason = rejected[0].reason.lower()
        assert [r.frame_counter for r in rejected] == [k] and ("crc" in reason or "zstd" in reason)


@pytest.mark.parametrize("bit", range(8))
def test_damaged_record_opcode_resyncs_at_the_next_chunk(clip101, tmp_path, bit):
    path, _, chunks = clip101

    def flip(data):
        data[chunks[4][0]] ^= 1 << bit  # chunk (0x06) -> message index, channel, footer, unknown, ...
    _, replayed, rejected = replay(damaged_copy(tmp_path, path, "op.mcap", flip))
    assert counters(replayed) == [c for c in range(101) if c != 4]
    assert [r.frame_counter for r in rejected] == [4] and f"bytes {chunks[4][0]}-" in rejected[0].reason


def test_chunk_without_crc_is_refused(clip101, tmp_path):
    path, _, chunks = clip101

    def zero_crc(data):
        crc_at = chunks[10][0] + 9 + 24  # after opcode+length, start/end time, uncompressed size
        data[crc_at:crc_at + 4] = b"\0\0\0\0"
    _, replayed, rejected = replay(damaged_copy(tmp_path, path, "z.mcap", zero_crc))
    assert 10 not in counters(replayed) and len(replayed) == 100
    assert [r.frame_counter for r in rejected] == [10] and "no CRC" in rejected[0].reason


def test_duplicated_frame_record_is_rejected_not_replayed_twice(clip101, tmp_path):
    path, _, chunks = clip101
    data = path.read_bytes()
    s, next_start = chunks[20][0], chunks[21][0]
    doubled = tmp_path / "dup.mcap"
    doubled.write_bytes(data[:next_start] + data[s:next_start] + data[next_start:])  # chunk 20 + its index again
    source, replayed, rejected = replay(doubled)
    assert counters(replayed) == list(range(101))
    assert [(r.frame_counter, r.reason.split(":")[0]) for r in rejected] == [(20, "duplicate")]
    assert source.stopped_reason == "end"


def test_invalid_frames_are_rejected_and_the_replay_goes_on(tmp_path):
    frames = [make_frame(c) for c in range(6)]
    frames[2] = dataclasses.replace(frames[2], range_m=np.ones((10, 10), np.float32),
                                    amplitude=np.ones((10, 10), np.float32), intrinsics=SMALL_INTRINSICS)
    frames[3] = dataclasses.replace(frames[3], host_monotonic_s=float("inf"))
    frames[4] = dataclasses.replace(frames[4], frame_counter=2**40)
    path = tmp_path / "bad.mcap"
    with RecordingWriter(path) as writer:
        for frame in frames:
            writer.write(frame)
    source, replayed, rejected = replay(path)
    assert counters(replayed) == [0, 1, 5]
    assert [r.frame_counter for r in rejected] == [2, 3, 2**40]
    assert all(r.reason.startswith("invalid_frame: ") for r in rejected)
    assert "(10, 10)" in rejected[0].reason and "host_monotonic_s" in rejected[1].reason
    assert "frame counter" in rejected[2].reason
    assert source.counters["invalid_frame"] == 3


def test_damaged_intrinsics_metadata_is_refused(tmp_path):
    path = tmp_path / "m.mcap"
    write_recording(path, range(3))
    data = path.read_bytes()
    fx = repr(Intrinsics().fx).encode()
    at = data.index(fx)
    changed = tmp_path / "fx.mcap"
    changed.write_bytes(other_digit(data, at + 5))  # one digit of fx
    with pytest.raises(DriverError, match="fails its CRC"):
        read_recording_info(changed)


def test_unsealed_metadata_of_format_1_files_is_checked_against_the_frames(tmp_path):
    data = V1_CLIP.read_bytes()
    fx = repr(read_recording_info(V1_CLIP).intrinsics.fx).encode()
    at = data.index(fx)
    assert b"crc32" not in data[:at + 400]  # the format-1 clip predates the metadata CRC
    changed = tmp_path / "fx.mcap"
    changed.write_bytes(other_digit(data, at + 5))
    with pytest.raises(DriverError, match="disagrees with the first frame"):
        read_recording_info(changed)


def test_damaged_replay_through_the_pipeline_ledgers_each_lost_and_invalid_frame(clip101, tmp_path):
    from tofd.config import Config
    from tofd.service.pipeline import Pipeline

    path, _, chunks = clip101
    data = path.read_bytes()

    def corrupt(d):
        d[chunks[5][1] - 500] ^= 0xFF
        d[chunks[7][1] - 500] ^= 0xFF
    damaged = damaged_copy(tmp_path, path, "p.mcap", corrupt)
    results = []
    pipeline = Pipeline(Config(), "lossless", writers=(results.append,))
    with ReplaySource(damaged, stop=12) as source:
        pipeline.start(source)
        assert pipeline.wait(120)
    summary = pipeline.close()
    assert data  # the original is untouched
    assert [r.frame.frame_counter for r in results] == [0, 1, 2, 3, 4, 6, 8, 9, 10, 11]
    assert summary["consistent"] and summary["frames_in"] == 12 and summary["frames_dropped"] == 2
    assert [(d["frame_counter"], d["stage"], d["reason"].split(":")[0]) for d in dropped_frames(summary)] == [
        (5, "capture", "damaged"), (7, "capture", "damaged")]
    assert summary["gaps"] == []


def other_digit(data: bytes, at: int) -> bytes:
    """`data` with the decimal digit at `at` replaced by the next one."""
    digit = int(chr(data[at]))
    return data[:at] + str((digit + 1) % 10).encode() + data[at + 1:]


def test_fuzzed_bundled_recording_never_escapes_an_exception(tmp_path):
    data = BUNDLED.read_bytes()
    reference = {f.frame_counter: f for f in collect(ReplaySource(BUNDLED))}
    rng = np.random.default_rng(17)
    for trial in range(30):
        path = tmp_path / "fuzz.mcap"
        path.write_bytes(mutate(data, rng)[1])
        try:
            read_recording_info(path)
            source = ReplaySource(path)
        except DriverError:
            continue  # refused with a clear error: fine
        replayed = collect(source)
        rejected = source.take_rejected()
        for frame in replayed:  # nothing damaged is ever replayed
            assert_frames_equal(reference[frame.frame_counter], frame)
        assert len({f.frame_counter for f in replayed}) == len(replayed), trial
        assert all(r.reason.split(":")[0] in ("damaged", "duplicate", "invalid_frame") for r in rejected)


def test_damaged_channel_records_still_replay_every_frame_by_the_fixed_channel_ids(tmp_path):
    path = tmp_path / "c.mcap"
    frames = write_recording(path, range(5))
    data = bytearray(path.read_bytes())
    at = data.index(b"/camera/range")
    data[at + 8] ^= 0x01  # the topic of the top-level channel record becomes "/camera/sange"
    damaged = tmp_path / "c2.mcap"
    damaged.write_bytes(bytes(data))
    source = ReplaySource(damaged)
    replayed = collect(source)
    assert counters(replayed) == [0, 1, 2, 3, 4]
    for a, b in zip(frames, replayed, strict=True):
        assert_frames_equal(a, b)
    with pytest.raises(DriverError, match="damaged recording header"):  # intrinsics etc. were skipped with it
        read_recording_info(damaged)


def test_replay_command_refuses_a_damaged_header_in_one_line(tmp_path, capsys):
    from tofd import cli

    data = V1_CLIP.read_bytes()
    at = data.index(repr(read_recording_info(V1_CLIP).intrinsics.fx).encode())
    changed = tmp_path / "fx.mcap"
    changed.write_bytes(other_digit(data, at + 5))
    assert cli.main(["replay", str(changed), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "disagrees with the first frame" in err[0] and "Traceback" not in err[0]


@pytest.mark.slow
def test_replay_command_ledgers_each_faulty_frame_and_replays_the_rest(tmp_path):
    """`tofd replay` (a real subprocess) of a recording with one frame of each fault: damaged, CRC 0,
    duplicated, 10x10 planes; exit 0, each faulty frame ledgered at capture with its reason, no traceback."""
    from tofd_testing.chaos_helpers import tofd
    from tofd_testing.pipeline_sources import write_config

    path = excerpt(BUNDLED, tmp_path / "clip.mcap", 14)
    faulty = {"malformed_frames": 3, "duplicated_frames": 6, "zero_crc_frames": 9, "damaged_frames": 12}
    assert set(faulty) == set(RECORDING_FAULTS)
    for i, (fault, counter) in enumerate(faulty.items()):
        path = faulty_copy(path, tmp_path / f"f{i}.mcap", fault, {counter})
    proc = tofd("replay", path, "--out", tmp_path / "out", "--rerun", "none", "--config", write_config(tmp_path))
    _, err = proc.communicate(timeout=300)  # a hang guard
    assert proc.returncode == 0 and "Traceback" not in err, err
    summary = json.loads((tmp_path / "out" / f"{path.stem}.summary.json").read_text())
    assert summary["consistent"] and summary["frames_in"] == summary["frames_out"] + summary["frames_dropped"]
    drops = sorted((d["frame_counter"], d["stage"], d["reason"].split(":")[0]) for d in dropped_frames(summary))
    assert drops == sorted((c, "capture", RECORDING_FAULTS[f]) for f, c in faulty.items()), drops
    assert summary["frames_out"] == 14 - 3  # the duplicate's original is replayed once
    zero_crc = next(d for d in dropped_frames(summary) if d["frame_counter"] == faulty["zero_crc_frames"])
    assert "no CRC" in zero_crc["reason"]
