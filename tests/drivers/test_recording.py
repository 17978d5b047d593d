"""RecordingWriter: lossless round trip of every Frame field, self-description, MCAP validity, crash safety."""

from __future__ import annotations

import dataclasses
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import tofd
from tests.commands.test_cli import CLIP
from tofd import cli
from tofd.drivers.frame import Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording import format as fmt
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import ReplaySource, iter_frames
from tofd.drivers.recording.schemas import RawImage
from tofd.drivers.recording.writer import RecordingWriter
from tofd_testing.recording_helpers import DEVICE, assert_frames_equal, make_frame, write_recording


@pytest.mark.parametrize("quantized", [True, False], ids=["usb-u16", "float32"])
def test_round_trip_keeps_every_field_bit_for_bit(tmp_path, quantized):
    path = tmp_path / "r.mcap"
    registers = Registers(int_time_code=12, mod_freq_index=0, acq_mode=1, data_source=0, amp_threshold=7)
    intrinsics = Intrinsics(fx=201.25, fy=199.5, cx=88.0, cy=70.75)
    frames = write_recording(path, range(1, 15), quantized=quantized, registers=registers, intrinsics=intrinsics)
    replayed = list(iter_frames(path))
    assert len(replayed) == len(frames)
    for a, b in zip(frames, replayed, strict=True):
        assert_frames_equal(a, b)
    assert any(f.ground_truth is None for f in replayed)
    assert any(f.ground_truth is not None and not f.ground_truth.visible for f in replayed)
    assert any(f.ground_truth is not None and f.ground_truth.nose_xyz_m is not None for f in replayed)


def encodings(frame) -> list[str]:
    """The RawImage encodings of a frame's range and amplitude messages."""
    messages = fmt.encode_frame(frame)
    return [RawImage.FromString(messages[i]).encoding for i in (1, 2)]


def test_usb_frames_are_stored_as_uint16_and_other_frames_as_float32():
    assert encodings(make_frame(3, quantized=True)) == ["16UC1", "16UC1"]
    assert encodings(make_frame(3, quantized=False)) == ["32FC1", "32FC1"]
    # a USB-like range plane with one pixel nudged by one ulp is no longer a uint16 conversion
    frame = make_frame(3)
    frame.range_m[50, 50] = np.nextafter(frame.range_m[50, 50], np.float32(10))
    assert encodings(frame) == ["32FC1", "16UC1"]


def test_planes_decode_writable(tmp_path):
    path = tmp_path / "r.mcap"
    write_recording(path, range(2))
    frame = next(iter_frames(path))
    frame.range_m[0, 0] = 1.0  # the pipeline may work in place
    frame.amplitude[0, 0] = 1.0


def test_header_describes_recording(tmp_path):
    path = tmp_path / "r.mcap"
    registers = Registers(int_time_code=40, mod_freq_index=1)
    write_recording(path, range(7, 10), registers=registers)
    info = read_recording_info(path)
    assert info.software_version == tofd.__version__
    assert info.format_version == fmt.FORMAT_VERSION
    assert info.device == DEVICE
    assert info.registers == registers
    assert info.intrinsics == Intrinsics()
    assert info.config == {"camera": {"serial": DEVICE.serial}}
    assert info.frame_count == 3


def test_a_camera_without_sr3000_registers_keeps_its_sensor_info_and_writes_no_registers(tmp_path):
    """Another camera's frames (registers None, a SensorInfo) come back the same, the header and the standard
    protobuf decoder see the sensor info; an SR3000 recording and the bundled clip have registers and no sensor."""
    sensor = SensorInfo(depth_unit_m=1e-3, amplitude="ir", amplitude_full_scale=65535.0, frame_period_s=1 / 30,
                        settings={"K4A_DEPTH_MODE": "NFOV_UNBINNED", "K4A_FPS": "FPS_30"})
    frames = [dataclasses.replace(make_frame(c, quantized=False), registers=None, sensor=sensor) for c in range(3)]
    path = tmp_path / "k.mcap"
    with RecordingWriter(path) as writer:
        for frame in frames:
            writer.write(frame)
    for a, b in zip(frames, iter_frames(path), strict=True):
        assert_frames_equal(a, b)
        assert b.registers is None and b.sensor == sensor and b.sensor.settings["K4A_DEPTH_MODE"] == "NFOV_UNBINNED"
    info = read_recording_info(path)
    assert (info.registers, info.sensor, info.device) == (None, sensor, DEVICE)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        assert fmt.META_REGISTERS not in {m.name for m in reader.iter_metadata()}
        headers = [m for _, c, _, m in reader.iter_decoded_messages() if c.topic == "/camera/frame"]
    assert len(headers) == 3 and not headers[0].HasField("registers")
    assert {s.key: s.value for s in headers[0].sensor.settings} == dict(sensor.settings)
    assert not headers[0].sensor.HasField("unambiguous_range_m")  # unknown stays unknown
    sr3000 = tmp_path / "sr.mcap"
    write_recording(sr3000, range(2))
    assert read_recording_info(sr3000).sensor is None and next(iter_frames(sr3000)).sensor is None
    clip = read_recording_info(CLIP)  # written before SensorInfo existed
    assert clip.sensor is None and clip.registers == Registers()
    first = next(iter_frames(CLIP))
    assert first.sensor is None and first.registers == Registers()


def test_sensor_info_names_a_bad_field_and_bad_metadata_is_a_format_error():
    with pytest.raises(ValueError, match="amplitude: 'colour'"):
        SensorInfo(1e-3, "colour")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="depth_unit_m"):
        SensorInfo(0.0, "ir")
    sealed = fmt.sensor_metadata(SensorInfo(1e-3, "active_brightness", settings={"mode": "5"}))
    assert fmt.sensor_from_metadata(fmt.check_metadata("s", sealed)).settings == {"mode": "5"}
    with pytest.raises(fmt.FormatError, match="SensorInfo.*settings"):
        fmt.sensor_from_metadata({"depth_unit_m": "0.001", "amplitude": '"ir"', "settings": "[1]"})


def test_file_is_standard_mcap_readable_by_the_mcap_library(tmp_path):
    path = tmp_path / "r.mcap"
    frames = write_recording(path, range(5))
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 5 * len(fmt.CHANNELS)
        assert summary.statistics.chunk_count == 5  # one chunk per frame: the unit of crash safety
        assert sorted(s.name for s in summary.schemas.values()) == sorted(fmt.SCHEMAS)
        assert all(s.encoding == "protobuf" for s in summary.schemas.values())
        assert [(c.id, c.topic) for c in summary.channels.values()] == [(c.id, c.topic) for c in fmt.CHANNELS]
        names = {m.name for m in reader.iter_metadata()}
        assert names == {fmt.META_RECORDING, fmt.META_INTRINSICS, fmt.META_DEVICE, fmt.META_REGISTERS}
        messages = list(reader.iter_messages())
    assert [c.topic for _, c, _ in messages] == [c.topic for c in fmt.CHANNELS] * 5  # each frame's in one chunk
    assert [m.sequence for _, _, m in messages] == [f.frame_counter for f in frames for _ in fmt.CHANNELS]
    assert [m.publish_time for _, _, m in messages] == [f.timestamp_us * 1000 for f in frames for _ in fmt.CHANNELS]
    assert [m.log_time for _, _, m in messages][::4] == [round(f.host_wall_s * 1e9) for f in frames]


def test_writer_rejects_frames_the_format_cannot_hold(tmp_path):
    with RecordingWriter(tmp_path / "r.mcap") as writer:
        for change, match in (({"frame_counter": 2**70}, "64-bit"), ({"timestamp_us": -1}, "timestamp_us"),
                              ({"host_wall_s": float("nan")}, "host_wall_s")):
            with pytest.raises(ValueError, match=match):
                writer.write(dataclasses.replace(make_frame(1), **change))
        writer.write(make_frame(2))  # the rejected frames left no trace
    assert [f.frame_counter for f in iter_frames(tmp_path / "r.mcap")] == [2]


def test_writer_rejects_planes_that_are_not_float32_of_the_image_shape(tmp_path):
    frame = make_frame(1)
    with RecordingWriter(tmp_path / "r.mcap") as writer:
        frame.range_m = frame.range_m.astype(np.float64)
        with pytest.raises(ValueError, match="frame.range_m: expected float32"):
            writer.write(frame)
        frame = make_frame(1)
        frame.amplitude = frame.amplitude[:-1]
        with pytest.raises(ValueError, match="frame.amplitude"):
            writer.write(frame)
        writer.write(make_frame(2))  # the rejected frames left no trace
    assert [f.frame_counter for f in iter_frames(tmp_path / "r.mcap")] == [2]
    assert read_recording_info(tmp_path / "r.mcap").frame_count == 1


def test_writer_rejects_bad_fsync_interval(tmp_path):
    with pytest.raises(ValueError, match="fsync_interval_s"):
        RecordingWriter(tmp_path / "r.mcap", fsync_interval_s=0)


def test_realistic_face_frames_stay_small(tmp_path):
    """Rendered SR3000-like frames (noise, flying pixels) as the USB backend delivers them: <= 100 kB each."""
    from tofd.drivers import sr3000
    from tofd.drivers.emulator.render import Pose, load_face, render_face

    mesh, rng = load_face("lee_perry_smith"), np.random.default_rng(1)
    path = tmp_path / "face.mcap"
    khz = sr3000.mod_freq_khz(Registers().mod_freq_index)
    with RecordingWriter(path) as writer:
        for i, d in enumerate(np.linspace(0.35, 0.70, 6)):
            r = render_face(mesh, Pose(distance_m=float(d)), rng=rng)
            frame = make_frame(i)
            frame.range_m = sr3000.raw_to_range_m(sr3000.range_m_to_raw(r.range_m, khz), khz)
            frame.amplitude = np.minimum(np.rint(r.amplitude), 65535).astype(np.float32)
            writer.write(frame)
    assert path.stat().st_size / 6 < 100_000


@pytest.fixture
def start_recorder():
    """Start `tofd record OUT --emulate` as a real process; returned once it has written a few frames.
    Any recorder still running at the end of the test is killed."""
    procs: list[subprocess.Popen] = []
    yield lambda out: _start_recorder(out, procs)
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _start_recorder(out, procs: list[subprocess.Popen]) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "record", str(out), "--emulate"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(proc)
    deadline = time.monotonic() + 60
    while not (out.exists() and out.stat().st_size > 500_000):  # a few frames are on disk
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "recorder wrote no frames in 60 s"
        time.sleep(0.05)
    return proc


def test_kill_9_mid_recording_keeps_every_frame_up_to_1s_before_the_kill(tmp_path, start_recorder):
    out = tmp_path / "killed.mcap"
    proc = start_recorder(out)
    time.sleep(2.0)
    size = out.stat().st_size
    while out.stat().st_size == size:  # kill just after a write: the recorder was running, not starved
        time.sleep(0.002)
    t_kill = time.time()
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    source = ReplaySource(out)
    frames = list(source)
    assert len(frames) >= 10  # ~2 s at 30 fps, less what a busy machine made the device drop
    assert frames[-1].host_wall_s >= t_kill - 1.0
    assert source.stopped_reason == "truncated" and source.counters["corrupt_tail"] == 1
    assert source.last_good_counter == frames[-1].frame_counter
    assert all(f.ground_truth is not None and f.device.backend == "emulated" for f in frames)
    counters = [f.frame_counter for f in frames]
    assert counters == sorted(counters)
    info = read_recording_info(out)
    assert info.frame_count is None and info.software_version == tofd.__version__ and info.config is not None


def test_sigterm_finishes_the_recording_cleanly(tmp_path, start_recorder):
    out = tmp_path / "term.mcap"
    proc = start_recorder(out)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "SIGTERM" in stderr and f"wrote {out}" in stdout
    source = ReplaySource(out)
    frames = list(source)
    assert source.stopped_reason == "end"
    assert read_recording_info(out).frame_count == len(frames) > 0


def test_record_command_writes_the_requested_frames_with_ground_truth(tmp_path):
    out = tmp_path / "n.mcap"
    assert cli.main(["record", str(out), "--emulate", "--frames", "12"]) == 0
    frames = list(iter_frames(out))
    assert len(frames) == 12
    counters = [f.frame_counter for f in frames]
    assert counters == sorted(set(counters))  # gaps only if the busy test machine made the device drop some
    assert all(f.ground_truth is not None and f.ground_truth.visible for f in frames)
    assert 0.34 < frames[0].ground_truth.nose_xyz_m[2] < 0.40  # the emulated face starts at 0.35 m
    with open(out, "rb") as f:
        images = [RawImage.FromString(m.data) for _, c, m in make_reader(f).iter_messages()
                  if c.topic in ("/camera/range", "/camera/amplitude")]
    assert {i.encoding for i in images} == {"16UC1"}  # as the camera sent it
    assert read_recording_info(out).config["camera"]["int_time_code"] == 30
