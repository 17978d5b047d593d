"""Recordings read by other tools: the official mcap reader with its protobuf decoder, Rerun's `rerun mcap convert`;
format-1 recordings still replay, and `tofd convert` rewrites them bit for bit."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from rerun.chunk import RrdReader

from tofd import cli
from tofd.drivers import sr3000
from tofd.drivers.recording import format as fmt
from tofd.drivers.recording.index import frame_index, read_chunks
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.recording_helpers import assert_frames_equal, write_recording
from tofd_testing.rrd_helpers import image_at

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "replay_data" / "emulated_face_035_070.mcap"
V1_CLIP = Path(__file__).resolve().parents[1] / "data" / "v1_first3.mcap"
"""The first 3 frames of the bundled clip as it was recorded in format 1 (before Foxglove's schemas)."""


def raw_range(frame) -> np.ndarray:
    """The device's uint16 distance values of a USB-like frame (0xFFFF where the range is NaN)."""
    scale = fmt.range_scales_m(frame.registers)[0]
    return np.where(np.isnan(frame.range_m), sr3000.RAW_INVALID, np.rint(frame.range_m / np.float64(scale)))


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("interop") / "r.mcap"
    return path, write_recording(path, range(1, 7))


def test_official_reader_decodes_every_message_into_its_schema_type(recording):
    path, frames = recording
    by_topic: dict[str, list] = {}
    with open(path, "rb") as f:
        for schema, channel, _, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            assert type(decoded).DESCRIPTOR.full_name == schema.name
            by_topic.setdefault(channel.topic, []).append(decoded)
    assert sorted(by_topic) == sorted(c.topic for c in fmt.CHANNELS)
    assert all(len(messages) == len(frames) for messages in by_topic.values())
    for frame, header, rng, amp, cal in zip(frames, *(by_topic[c.topic] for c in fmt.CHANNELS), strict=True):
        assert (header.frame_counter, header.timestamp_us) == (frame.frame_counter, frame.timestamp_us)
        assert header.host_wall_s == frame.host_wall_s and header.registers.int_time_code == 30
        assert header.HasField("ground_truth") == (frame.ground_truth is not None)
        for image in (rng, amp):
            assert (image.width, image.height, image.encoding, image.frame_id) == (176, 144, "16UC1", "camera")
            assert image.timestamp.ToNanoseconds() == round(frame.host_wall_s * 1e9)
        np.testing.assert_array_equal(np.frombuffer(rng.data, "<u2").reshape(144, 176), raw_range(frame))
        np.testing.assert_array_equal(np.frombuffer(amp.data, "<u2").reshape(144, 176), frame.amplitude)
        i = frame.intrinsics
        assert list(cal.K) == [i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1] and (cal.width, cal.height) == (176, 144)
        assert cal.frame_id == "camera"


def rerun_cli() -> str:
    """The `rerun` CLI that rerun-sdk installs beside this Python."""
    found = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    assert found, "the rerun CLI of rerun-sdk is not installed"
    return found


def rrd_tables(path: Path) -> dict[str, pa.Table]:
    """entity path -> its temporal rows (all chunks), sorted by MCAP log time."""
    chunks = [c for c in RrdReader(str(path)).stream().to_chunks() if not c.is_static]
    tables = {}
    for entity in {c.entity_path for c in chunks}:
        batches = [c.to_record_batch() for c in chunks if c.entity_path == entity]
        tables[entity] = pa.Table.from_batches(batches).sort_by("message_log_time")
    return tables


def test_rerun_mcap_convert_shows_range_and_amplitude_images_with_the_pinhole(recording, tmp_path):
    path, frames = recording
    rrd = tmp_path / "r.rrd"
    proc = subprocess.run([rerun_cli(), "mcap", "convert", str(path), "-o", str(rrd)], capture_output=True,
                          text=True, timeout=300, env={**os.environ, "RUST_LOG": "error"})
    assert proc.returncode == 0, proc.stderr
    tables = rrd_tables(rrd)
    n = len(frames)
    for k, frame in enumerate(frames):
        rng = image_at(tables["/camera/range"], "Image", k)
        amp = image_at(tables["/camera/amplitude"], "Image", k)
        assert rng.dtype == amp.dtype == np.uint16
        np.testing.assert_array_equal(rng, raw_range(frame))
        np.testing.assert_array_equal(amp, frame.amplitude)
    pinhole = tables["/camera/calibration"]
    assert pinhole.num_rows == n
    i = frames[0].intrinsics
    k = np.array(pinhole.column("Pinhole:image_from_camera")[0].as_py()[0]).reshape(3, 3).T  # column-major
    np.testing.assert_allclose(k, [[i.fx, 0, i.cx], [0, i.fy, i.cy], [0, 0, 1]], rtol=1e-7)  # stored as float32
    assert pinhole.column("Pinhole:resolution")[0].as_py() == [[176.0, 144.0]]
    image_plane = pinhole.column("Pinhole:child_frame")[0].as_py()
    for entity in ("/camera/range", "/camera/amplitude"):  # the images sit in the pinhole's image plane
        assert tables[entity].column("CoordinateFrame:frame").to_pylist() == [image_plane] * n
    header = tables["/camera/frame"].column("tofd.FrameHeader:message").to_pylist()
    assert [h[0]["frame_counter"] for h in header] == [f.frame_counter for f in frames]


def test_format_1_recordings_still_replay_bit_for_bit():
    old = list(iter_frames(V1_CLIP))
    assert read_recording_info(V1_CLIP).format_version == 1
    assert read_recording_info(BUNDLED).format_version == fmt.FORMAT_VERSION
    new = list(iter_frames(BUNDLED, stop=len(old)))  # the bundled clip, converted from format 1
    assert len(old) == len(new) == 3
    for a, b in zip(old, new, strict=True):
        assert_frames_equal(a, b)


def test_convert_command_rewrites_a_format_1_recording_in_the_current_format(tmp_path, capsys):
    out = tmp_path / "v2.mcap"
    assert cli.main(["convert", str(V1_CLIP), str(out)]) == 0
    assert f"wrote {out}: 3 frames (format 1 -> {fmt.FORMAT_VERSION})" in capsys.readouterr().err
    for a, b in zip(iter_frames(V1_CLIP), iter_frames(out), strict=True):
        assert_frames_equal(a, b)
    info, old = read_recording_info(out), read_recording_info(V1_CLIP)
    assert info.format_version == fmt.FORMAT_VERSION and info.frame_count == 3
    assert (info.config, info.intrinsics, info.device, info.registers) == (old.config, old.intrinsics, old.device,
                                                                          old.registers)
    assert [p.name for p in tmp_path.iterdir()] == ["v2.mcap"]  # no temp file left beside it


@pytest.mark.parametrize("path", [V1_CLIP, BUNDLED], ids=["format-1", "format-2"])
def test_chunk_index_reads_frames_of_either_format(path):
    with open(path, "rb") as f:
        index = frame_index(f)
        chunks = list(read_chunks(f, index, 1, 3))
    assert [c.error for c in chunks] == ["", ""]
    for chunk, expected in zip(chunks, list(iter_frames(path, start=1, stop=3)), strict=True):
        (frame,) = chunk.frames
        assert_frames_equal(expected, frame)
