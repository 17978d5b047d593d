"""Every reader bounds what a file can make it allocate, and the drop ledger stays small however much is lost:
drop ranges instead of one entry per frame, compression bombs in ROS 1 chunks, PNG and raw images declaring
more pixels than any time-of-flight camera has, a cut sqlite3 bag claiming gigabytes of pages, calibrations
no camera has (tofd_testing/hostile_bags.py builds the files)."""

from __future__ import annotations

import json
import resource
import shutil
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from tofd.drivers.bags import scan
from tofd.drivers.bags.camera_info import lens_intrinsics
from tofd.drivers.bags.driver_bag import RangeOptions, RosbagSource
from tofd.drivers.bags.images import compressed_plane, encoded_size, image_plane
from tofd.drivers.bags.scan import BagError, DamagedMessage
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.limits import MAX_IMAGE_PIXELS
from tofd.drivers.recording.index import frame_index, read_chunks
from tofd.drivers.recording.replay import ReplaySource
from tofd.service.pipeline.ledger import LISTED, DropLedger
from tofd_testing.hostile_bags import mcap_chunk_bomb, png_header, ros1_chunk_bomb, sqlite_page_claim
from tofd_testing.pipeline_sources import rejected_counters
from tofd_testing.recording_helpers import frame_spans, make_frame, write_recording
from tofd_testing.rosbag_helpers import frame_messages, typestore, write_bag, write_frames_bag


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _read_bag(path):
    """(frame counters read, counters lost, the damage named) of a RosbagSource over the bag at `path`."""
    with RosbagSource(path, RangeOptions()) as source:
        return [f.frame_counter for f in source], rejected_counters(source), source.bag.damage


# ---------------------------------------------------------------- the ledger

def test_the_ledger_keeps_ranges_and_its_summary_stays_small():
    ledger = DropLedger()
    ledger.lost(0, 5, 2**31, "damaged: bytes 100-200: a chunk fails its CRC")  # one range, however long
    seq = 1
    for k in range(3 * LISTED):  # frames dropped one by one, each for its own reason, counters not consecutive
        ledger.admit(seq, 2**31 + 10 + 2 * k)
        ledger.drop(seq, "capture", f"invalid_frame: problem {k}")
        ledger.mark_gap(2**31 + 10 + 2 * k, 2**31 + 12 + 2 * k, "counter_gap")
        ledger.skip_viewer(seq, 2**31 + 10 + 2 * k, "blocked")
        seq += 1
    for k in range(50):  # consecutive counters and sequence numbers, one stage and reason: one range
        ledger.admit(seq, 2**32 - 100 + k)
        ledger.drop(seq, "features", "worker_died")
        seq += 1
    summary = ledger.summary()
    text = json.dumps(summary)
    assert len(text) < 1 << 20
    assert summary["consistent"] and summary["frames_in"] == 2**31 + 3 * LISTED + 50
    assert summary["frames_dropped"] == 2**31 + 3 * LISTED + 50 and ledger.frames_dropped == summary["frames_dropped"]
    assert summary["dropped_by_reason"] == {"capture/damaged": 2**31, "capture/invalid_frame": 3 * LISTED,
                                            "features/worker_died": 50}
    assert len(summary["drops"]) == LISTED and summary["drops_unlisted"] == 1 + 3 * LISTED + 50 - LISTED
    assert summary["drops"][0] == {"frame_counter": 5, "seq": 0, "stage": "capture",
                                   "reason": "damaged: bytes 100-200: a chunk fails its CRC", "frames": 2**31}
    assert len(summary["gaps"]) == LISTED and summary["device_gaps"] == 3 * LISTED
    assert summary["viewer_dropped"] == 3 * LISTED and summary["viewer_dropped_by_reason"] == {"blocked": 3 * LISTED}


def test_consecutive_drops_merge_into_one_range():
    ledger = DropLedger()
    for seq in range(10):
        ledger.admit(seq, 100 + seq)
    for seq in (0, 1, 2, 5, 6):
        ledger.drop(seq, "features", "late")
    ledger.drop(3, "sink", "queue_full")
    drops = ledger.summary()["drops"]
    assert [(d["frame_counter"], d["frames"], d["stage"]) for d in drops] == [
        (100, 3, "features"), (105, 2, "features"), (103, 1, "sink")]


def test_a_damaged_chunk_before_a_counter_jump_is_one_lost_frame_to_replay_and_to_the_chunk_index(tmp_path):
    counters = [0, 1, 2, 3, 2**31, 2**31 + 1, 2**31 + 2, 3 * 2**30]
    path = tmp_path / "jumps.mcap"
    write_recording(path, counters)
    spans = frame_spans(path)
    data = bytearray(path.read_bytes())
    for k in (3, 6):  # frames 3 and 2**31 + 2: a counter jump follows each
        data[spans[k][2] - 300] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))

    with ReplaySource(damaged) as source:
        replayed = [f.frame_counter for f in source]
        rejected = source.take_rejected()
    assert replayed == [0, 1, 2, 2**31, 2**31 + 1, 3 * 2**30]
    assert [(r.frame_counter, r.frames) for r in rejected] == [(3, 1), (2**31 + 2, 1)]
    with open(damaged, "rb") as f:
        index = frame_index(f)
        assert index is not None
        chunks = list(read_chunks(f, index, 0, index.chunk_count))
    assert sum(1 for c in chunks if c.error) == sum(r.frames for r in rejected)  # what `tofd batch` counts


# ---------------------------------------------------------------- ROS bags

@pytest.mark.parametrize("compression", ["bz2", "lz4"])
def test_a_ros1_chunk_bomb_is_damage_where_it_starts_and_never_decompressed_whole(tmp_path, monkeypatch, compression):
    monkeypatch.setattr(scan, "MAX_CHUNK_BYTES", 4 << 20)  # a bomb of 24 MiB is quick to make
    ts = typestore("ros1")
    frames = [make_frame(c) for c in range(6)]
    bag = write_bag(tmp_path / "clip.bag", "ros1", (m for f in frames for m in frame_messages(ts, f)),
                    chunk_bytes=1 << 10, compression=compression)
    bomb = ros1_chunk_bomb(bag, tmp_path / "bomb.bag", 24 << 20)
    before = _peak_rss_mb()
    got, lost, damage = _read_bag(bomb)
    assert got == [f.frame_counter for f in frames[:len(got)]] and len(got) >= 4
    assert lost == [len(got)] and "decompresses to more than 4194304 bytes" in damage
    assert _peak_rss_mb() - before < 20  # 24 MiB if the chunk were decompressed whole


def test_a_ros2_mcap_chunk_bomb_is_damage_where_it_starts_and_never_decompressed_whole(tmp_path, monkeypatch):
    monkeypatch.setattr(scan, "MAX_CHUNK_BYTES", 4 << 20)
    frames = [make_frame(c) for c in range(5)]
    (original,) = write_frames_bag(tmp_path, "mcap", frames).glob("*.mcap")
    bomb = mcap_chunk_bomb(original, tmp_path / "bomb.mcap", 24 << 20)
    before = _peak_rss_mb()
    got, lost, damage = _read_bag(bomb)
    assert got + lost == [f.frame_counter for f in frames] and len(got) >= 4  # the frames before the bomb
    assert "decompresses to more than 4194304 bytes" in damage
    assert _peak_rss_mb() - before < 20  # 24 MiB if the chunk were decompressed whole


def test_a_cut_sqlite_bag_claiming_gigabytes_of_pages_is_read_as_the_pages_it_has(tmp_path):
    frames = [make_frame(c) for c in range(8)]
    bag = write_frames_bag(tmp_path, "sqlite3", frames)
    cut = tmp_path / "cut"
    cut.mkdir()
    (db3,) = bag.glob("*.db3")
    sqlite_page_claim(db3, cut / db3.name, 0.6, 2 << 30)
    shutil.copy(bag / "metadata.yaml", cut / "metadata.yaml")
    before = _peak_rss_mb()
    got, _, damage = _read_bag(cut)
    assert got == [f.frame_counter for f in frames[:len(got)]] and 1 <= len(got) < len(frames)
    assert damage and "sqlite3" in damage
    assert _peak_rss_mb() - before < 50  # 2 GiB if padded to the claim


def test_a_png_declaring_30000x30000_is_refused_from_its_header():
    png = png_header(30000, 30000)
    assert encoded_size(png) == (30000, 30000) and len(png) < 1 << 20
    message = SimpleNamespace(format="16UC1; compressedDepth png",
                              data=np.frombuffer(bytes(12) + png, np.uint8))
    before = _peak_rss_mb()
    with pytest.raises(DamagedMessage, match="image size 30000 x 30000: larger than any time-of-flight camera"):
        compressed_plane(message, {"16UC1": "u2"}, "/camera/depth/compressedDepth")
    assert _peak_rss_mb() - before < 50  # 1.8 GB if decoded


def test_encoded_sizes_of_real_png_and_jpeg_files_are_read_from_their_headers():
    image = np.arange(37 * 53, dtype=np.uint16).reshape(37, 53)
    assert encoded_size(cv2.imencode(".png", image)[1].tobytes()) == (53, 37)
    assert encoded_size(cv2.imencode(".jpg", (image % 256).astype(np.uint8))[1].tobytes()) == (53, 37)
    assert encoded_size(b"BM not a png") is None
    ok = SimpleNamespace(format="16UC1; compressedDepth png",
                         data=np.frombuffer(bytes(12) + cv2.imencode(".png", image)[1].tobytes(), np.uint8))
    np.testing.assert_array_equal(compressed_plane(ok, {"16UC1": "u2"}, "/d"), image)


def test_a_raw_image_beyond_the_pixel_cap_is_refused_before_its_bytes_are_touched():
    side = 8192
    message = SimpleNamespace(encoding="16UC1", is_bigendian=0, height=side, width=side, step=2 * side,
                              data=np.zeros(16, np.uint8))
    with pytest.raises(DamagedMessage, match=f"image size {side} x {side}: larger than any time-of-flight camera"):
        image_plane(message, {"16UC1": "u2"}, "/camera/depth")
    assert side * side > MAX_IMAGE_PIXELS


@pytest.mark.parametrize(("size", "k", "match"), [
    ((8192, 8192), (500.0, 500.0, 4096.0, 4096.0), "image size 8192 x 8192"),
    ((640, 480), (1e-300, 500.0, 320.0, 240.0), "fx: expected a finite focal length"),
    ((640, 480), (500.0, 500.0, 1e12, 240.0), "cx: expected a finite principal point"),
    ((640, 480), (500.0, float("nan"), 320.0, 240.0), "fy: expected a finite focal length"),
])
def test_a_calibration_no_camera_has_is_refused_by_the_rule_every_input_shares(size, k, match):
    with pytest.raises(BagError, match=match):
        lens_intrinsics(*size, k, None, None, "/camera/camera_info")
    with pytest.raises(ValueError, match=match):  # the recordings', the config's and the library's rule
        Intrinsics(*size, *k)


def test_info_on_a_fifo_refuses_it_without_opening_it(tmp_path):
    import os
    import subprocess
    import sys

    fifo = tmp_path / "capture.mcap"
    os.mkfifo(fifo)
    proc = subprocess.run([sys.executable, "-m", "tofd", "info", str(fifo)], capture_output=True, text=True,
                          timeout=120)  # a hang guard: opening the FIFO would block without a writer
    assert proc.returncode == 2 and "not a regular file" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and str(fifo) in proc.stderr


def test_the_library_refuses_a_transfer_stack_beyond_its_bound_before_copying_it():
    import tofd
    from tofd.algorithm.features.operators import MAX_OPERATORS

    frame = make_frame(0)
    before = _peak_rss_mb()
    with pytest.raises(ValueError, match=f"transfer returned 100000 operators, at most {MAX_OPERATORS}"):
        tofd.surface_filter(frame.range_m, frame.intrinsics,
                            lambda kx, ky: np.broadcast_to(np.ones_like(kx), (100_000, *kx.shape)))
    assert _peak_rss_mb() - before < 100  # gigabytes if the stack were copied
    with pytest.raises(ValueError, match="image size 8192 x 8192"):  # so no image of that size reaches it either
        tofd.Intrinsics(8192, 8192, 5000.0, 5000.0, 4095.5, 4095.5)


def test_info_on_a_recording_whose_every_frame_is_damaged_says_nothing_readable(tmp_path):
    import subprocess
    import sys

    path = tmp_path / "all.mcap"
    write_recording(path, range(4))
    data = bytearray(path.read_bytes())
    for _, _, end in frame_spans(path)[1:]:  # every frame but the first, whose span holds the header
        data[end - 300] ^= 0xFF
    first_end = frame_spans(path)[0][2]
    data[first_end - 300] ^= 0xFF
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    proc = subprocess.run([sys.executable, "-m", "tofd", "info", str(damaged)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "nothing readable: no frame (" in last and "none found" not in proc.stderr + proc.stdout, proc.stderr
