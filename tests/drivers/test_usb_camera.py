"""UsbCamera through pyusb on the emulated device: every fault of the protocol's table is survived and counted."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tofd.drivers.emulator.backend import EmulatedCamera, EmulatedSR3000, EmulatorBackend
from tofd.drivers.usb.camera import UsbCamera, list_devices
from tofd.drivers.usb.errors import AccessDenied, DeviceNotFound
from tofd.drivers.usb.protocol import Register

C = 299_792_458.0


def take(camera, n, after=None):
    """The next n frames; after(i) is called once frame i has arrived (to inject a fault mid-stream)."""
    frames = []
    for frame in camera:
        frames.append(frame)
        if after is not None:
            after(len(frames) - 1)
        if len(frames) == n:
            return frames
    raise AssertionError(f"stream ended after {len(frames)} frames")


def counter_gaps(frames):
    counters = np.array([f.frame_counter for f in frames])
    return int(np.sum(np.diff(counters) - 1))


def device_truth(camera):
    """Frames the device says it dropped, as of the last frame the host received."""
    return camera.last_header.dropped_total


def test_streams_test_pattern_exactly(make_emulated_camera):
    camera = make_emulated_camera()
    frames = take(camera, 5)
    u = np.arange(176)
    v = np.arange(144)
    expected_range = (u * 65535 // 175) / 65535 * C / (2 * 20e6)
    for f in frames:
        assert f.range_m.dtype == np.float32 and f.amplitude.dtype == np.float32
        np.testing.assert_allclose(f.range_m[:, :175], np.broadcast_to(expected_range[:175], (144, 175)), rtol=1e-6)
        assert np.isnan(f.range_m[:, 175]).all()  # raw 0xFFFF: end of the non-ambiguity range
        np.testing.assert_array_equal(f.amplitude, np.broadcast_to((v * 65535 // 143)[:, None], (144, 176)))
        assert f.registers.data_source == 1 and f.registers.int_time_code == 0 and f.registers.mod_freq_index == 3
        assert f.device.serial == "30000001" and f.device.firmware == "1.0" and f.device.backend == "emulated"
        assert f.ground_truth is None
    assert [f.frame_counter for f in frames] == sorted({f.frame_counter for f in frames})
    assert np.all(np.diff([f.timestamp_us for f in frames]) > 0)
    assert np.all(np.diff([f.host_monotonic_s for f in frames]) >= 0)
    assert camera.counters["frames"] == 5


@pytest.mark.parametrize("mod_index", [0, 4])
def test_modulation_frequency_applied_and_used_for_metres(make_emulated_camera, mod_index):
    camera = make_emulated_camera(mod_freq_index=mod_index)
    assert camera.emulator.registers[Register.MOD_FREQ] == mod_index
    frame = take(camera, 1)[0]
    f_mod = (40e6, 30e6, 21e6, 20e6, 19e6)[mod_index]
    assert frame.registers.mod_freq_index == mod_index
    np.testing.assert_allclose(frame.range_m[0, 100], (100 * 65535 // 175) / 65535 * C / (2 * f_mod), rtol=1e-6)


def test_scene_frames_carry_ground_truth(make_emulated_camera):
    camera = make_emulated_camera(test_pattern=False)
    frames = take(camera, 3)
    for f in frames:
        truth = f.ground_truth
        assert truth is not None and truth.visible
        u, v = (round(c) for c in truth.nose_px)
        assert 0.34 < np.linalg.norm(truth.nose_xyz_m) < 0.71
        # the range measured at the nose pixel is the nose tip's distance (noise of a few mm at the nose)
        assert abs(f.range_m[v, u] - np.linalg.norm(truth.nose_xyz_m)) < 0.02
        assert truth == camera.emulator.ground_truth(f.frame_counter)


def test_timeouts_are_retried_and_counted(make_emulated_camera):
    camera = make_emulated_camera()
    frames = take(camera, 20, after=lambda i: i == 4 and camera.emulator.inject_timeouts(3))
    assert camera.counters["timeout"] == 3
    assert camera.counters["device_dropped"] == device_truth(camera) == counter_gaps(frames)
    assert camera.counters["device_dropped"] > 0  # 60 ms of timeouts overran the 4-frame FIFO


def test_stall_is_reported_after_stall_time_and_marked_as_gap(make_emulated_camera):
    gaps, paused_at = [], []
    camera = make_emulated_camera(on_gap=gaps.append)

    def pause(i: int) -> None:
        if i == 4:
            paused_at.append(time.monotonic())  # the emulator's clock
            camera.emulator.pause(1.0)

    frames = take(camera, 10, after=pause)
    assert camera.counters["stall"] == 1
    assert camera.counters["timeout"] >= 5  # 1 s of 20 ms reads (5 even if each took ten times its timeout)
    assert len(gaps) == 1 and list(camera.gaps) == gaps
    gap = gaps[0]
    # the frames the sensor had finished before it paused (at most a FIFO's worth) come first, then the gap
    counters = [f.frame_counter for f in frames]
    k = counters.index(gap.last_counter)
    assert 4 <= k <= 4 + camera.emulator.fifo_depth and gap.next_counter == counters[k + 1]
    assert gap.kind == "stall" and gap.start_monotonic_s >= frames[4].host_monotonic_s
    assert gap.end_monotonic_s >= paused_at[0] + 1.0  # nothing was produced before the pause ended
    assert camera.counters["device_dropped"] == device_truth(camera)


@pytest.mark.parametrize("kind", ["partial", "payload_crc", "header_crc"])
def test_damaged_frames_are_dropped_and_counted(make_emulated_camera, kind):
    camera = make_emulated_camera()
    inject = {"partial": lambda: camera.emulator.inject_partial_frames(2),
              "payload_crc": lambda: camera.emulator.inject_crc_errors(2, "payload"),
              "header_crc": lambda: camera.emulator.inject_crc_errors(2, "header")}[kind]
    frames = take(camera, 12, after=lambda i: i == 3 and inject())
    key = "partial_frame" if kind == "partial" else "crc_error"
    assert camera.counters[key] == 2
    assert sum(camera.counters[k] for k in ("partial_frame", "crc_error", "bad_header")) == 2
    # the two damaged frames show as a counter gap but are the host's drops, not the device's
    assert camera.counters["device_dropped"] == device_truth(camera) == counter_gaps(frames) - 2
    for f in frames:  # every delivered frame is intact
        assert np.isnan(f.range_m[:, 175]).all() and not np.isnan(f.range_m[:, :175]).any()


def test_endpoint_stall_is_cleared(make_emulated_camera):
    camera = make_emulated_camera()
    take(camera, 10, after=lambda i: i == 2 and camera.emulator.inject_stall())
    assert camera.counters["endpoint_stall"] == 1
    assert camera.emulator.halted == set()


@pytest.mark.parametrize("n, reopened", [(2, 0), (5, 1)])
def test_io_errors_are_retried_then_the_device_is_reopened(make_emulated_camera, n, reopened):
    camera = make_emulated_camera(int_time_code=2)
    take(camera, 8, after=lambda i: i == 2 and camera.emulator.inject_io_errors(n))
    assert camera.counters["io_error"] == n
    assert camera.counters["reopen_after_io_errors"] == camera.counters["reconnect"] == reopened
    assert camera.counters["unplug"] == 0 and camera.emulator.registers[Register.INT_TIME] == 2


@pytest.mark.parametrize("dropped", [True, False])
def test_counter_gap_counts_device_drops(make_emulated_camera, dropped):
    camera = make_emulated_camera()
    frames = take(camera, 10, after=lambda i: i == 2 and camera.emulator.inject_counter_gap(50, dropped))
    natural = device_truth(camera) - (50 if dropped else 0)  # overruns of a busy machine, if any
    assert camera.counters["device_dropped"] == 50 + natural == counter_gaps(frames)


def test_slow_host_overruns_fifo_and_drops_are_counted(make_emulated_camera):
    camera = make_emulated_camera(device={"fifo_depth": 3})
    stop = threading.Event()
    frames = take(camera, 12, after=lambda i: i == 2 and stop.wait(0.1))  # the consumer dawdles 100 ms
    assert camera.counters["device_dropped"] >= 50  # ~77 frames produced in 100 ms, 3 fit in the FIFO
    assert camera.counters["device_dropped"] == device_truth(camera) == counter_gaps(frames)
    assert camera.emulator.status().frames_dropped >= camera.counters["device_dropped"]


def test_unplug_replug_resumes_same_serial_with_registers_restored(make_emulated_camera):
    gaps = []
    camera = make_emulated_camera(int_time_code=3, on_gap=gaps.append)
    camera.set_register(Register.AMP_THR_LO, 0x42, via="bulk")
    emulator = camera.emulator
    address_before = emulator.address
    frames = take(camera, 15, after=lambda i: i == 6 and emulator.unplug(replug_after_s=0.1))
    assert camera.counters["unplug"] == 1 and camera.counters["reconnect"] == 1
    assert camera.counters["reconnect_attempt"] >= 2  # the first attempts find no device (backoff)
    assert emulator.address != address_before
    assert camera.serial == "30000001" and frames[-1].device.serial == "30000001"
    regs = emulator.registers
    assert (regs[Register.INT_TIME], regs[Register.DATA_SOURCE], regs[Register.AMP_THR_LO]) == (3, 1, 0x42)
    assert all(f.registers.int_time_code == 3 and f.registers.data_source == 1 for f in frames)
    after = frames[7:]
    assert after[0].frame_counter < frames[6].frame_counter  # the device restarted its counter
    assert [g.kind for g in gaps] == ["reconnect"]
    assert gaps[0].last_counter == frames[6].frame_counter and gaps[0].next_counter == after[0].frame_counter
    assert gaps[0].end_monotonic_s - gaps[0].start_monotonic_s >= 0.1
    assert camera.counters["device_dropped"] == counter_gaps(frames[:7]) + counter_gaps(after)


def test_close_from_another_thread_ends_iteration_while_reconnecting(make_emulated_camera):
    camera = make_emulated_camera()
    frames = take(camera, 3, after=lambda i: i == 2 and camera.emulator.unplug())  # never comes back
    timer = threading.Timer(0.2, camera.close)
    timer.start()
    assert list(camera) == []  # blocks in the reconnect loop until close()
    timer.join()
    assert camera.counters["unplug"] == 1 and camera.counters["reconnect"] == 0
    assert camera.counters["reconnect_attempt"] >= 2 and len(frames) == 3


def test_register_writes_round_trip_control_and_bulk(make_emulated_camera):
    camera = make_emulated_camera()
    camera.set_register(0x10, 0xA5, via="control")
    camera.set_register(0x11, 0x5A, via="bulk")
    camera.set_register(Register.INT_TIME, 7, via="bulk")
    assert camera.emulator.registers[0x10:0x12] == bytes([0xA5, 0x5A])
    assert camera.registers.int_time_code == 7
    assert take(camera, 2)[-1].registers.int_time_code == 7


@pytest.mark.parametrize("register, value", [(0x3F, 1), (64, 0), (0x10, 256), (Register.MOD_FREQ, 5)])
def test_refused_register_writes_name_the_problem(make_emulated_camera, register, value):
    camera = make_emulated_camera()
    with pytest.raises(ValueError, match=f"{register:02X}|{value}"):
        camera.set_register(register, value)


def test_open_by_serial_among_several_and_listing():
    devices = [EmulatedSR3000("0000AAAA", address=3), EmulatedSR3000("0000BBBB", address=4)]
    backend = EmulatorBackend(*devices)
    listings = list_devices(backend)
    assert [(d.bus, d.address, d.serial, d.firmware) for d in listings] == [
        (1, 3, "0000AAAA", "1.0"), (1, 4, "0000BBBB", "1.0")]
    assert listings[0].registers.int_time_code == 30 and listings[0].registers.mod_freq_index == 3
    with UsbCamera("0000bbbb", backend=backend) as camera:
        assert camera.serial == "0000BBBB"
    with UsbCamera(backend=backend) as camera:
        assert camera.serial == "0000AAAA"  # the first one found
    with pytest.raises(DeviceNotFound, match="with serial 12345678; found: 0000AAAA, 0000BBBB"):
        UsbCamera("12345678", backend=backend)


def test_no_device_and_access_denied_messages():
    emulator = EmulatedSR3000()
    emulator.unplug()
    with pytest.raises(DeviceNotFound, match="no SR3000-style camera .*none attached"):
        UsbCamera(backend=EmulatorBackend(emulator))
    backend = EmulatorBackend(EmulatedSR3000(access_denied=True))
    with pytest.raises(AccessDenied, match="70-tofd-sr3000.rules"):
        UsbCamera(backend=backend)
    (listing,) = list_devices(backend)
    assert listing.serial is None and "udev rule" in listing.error


def test_access_denied_hint_names_the_shipped_udev_rule():
    """The file the hint tells the user to `sudo cp` exists and is the camera's rule."""
    with pytest.raises(AccessDenied) as denied:
        UsbCamera(backend=EmulatorBackend(EmulatedSR3000(access_denied=True)))
    copied = re.search(r"sudo cp (\S+) /etc/udev/rules.d/", str(denied.value))
    assert copied is not None, str(denied.value)
    rule = Path(copied.group(1))
    assert rule.is_file() and rule.name == "70-tofd-sr3000.rules"
    assert 'ATTRS{idVendor}=="0852", ATTRS{idProduct}=="0074"' in rule.read_text()


def test_bad_arguments_name_themselves():
    backend = EmulatorBackend()
    with pytest.raises(ValueError, match="int_time_code"):
        UsbCamera(int_time_code=300, backend=backend)
    with pytest.raises(ValueError, match="mod_freq_index"):
        UsbCamera(mod_freq_index=5, backend=backend)
    with pytest.raises(ValueError, match="serial"):
        UsbCamera("XYZ", backend=backend)


def test_camera_config_keywords_match(make_emulated_camera):
    import dataclasses

    from tofd.config import CameraConfig
    from tofd.service.camera import sr3000_keywords

    config = dataclasses.replace(CameraConfig(), serial="30000001", int_time_code=0, read_timeout_s=0.02)
    camera = EmulatedCamera(EmulatedSR3000("30000001", readout_s=0.0005), **sr3000_keywords(config))
    with camera:
        assert take(camera, 2)[-1].registers.int_time_code == 0


def test_tofd_devices_emulate(capsys):
    from tofd.cli import main

    assert main(["devices", "--emulate"]) == 0
    out = capsys.readouterr().out
    assert "30000001" in out and "6.2 ms" in out and "20 MHz" in out and "1.0" in out


def test_frames_carry_the_amplitude_threshold_set_while_streaming(make_emulated_camera, tmp_path):
    from tofd.drivers.recording.replay import iter_frames
    from tofd.drivers.recording.writer import RecordingWriter

    camera = make_emulated_camera()
    before = take(camera, 2)
    camera.set_register(Register.AMP_THR_LO, 0x34)
    camera.set_register(Register.AMP_THR_HI, 0x12, via="bulk")
    after = take(camera, 3)
    assert {f.registers.amp_threshold for f in before} == {0}
    assert {f.registers.amp_threshold for f in after} == {0x1234}
    path = tmp_path / "thr.mcap"
    with RecordingWriter(path) as writer:
        for frame in before + after:
            writer.write(frame)
    assert [f.registers.amp_threshold for f in iter_frames(path)] == [0, 0, 0x1234, 0x1234, 0x1234]


def test_power_up_registers_of_the_camera_are_the_frame_defaults(small_scene):
    from tofd.config import CameraConfig
    from tofd.drivers.frame import Registers
    from tofd.drivers.usb.device import registers_from_bank

    emulator = EmulatedSR3000("30000009", small_scene)
    assert registers_from_bank(bytes(emulator.registers)) == Registers()  # the emulator's power-up bank
    cfg = CameraConfig()
    assert (cfg.int_time_code, cfg.mod_freq_index) == (Registers().int_time_code, Registers().mod_freq_index)
