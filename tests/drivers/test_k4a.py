"""Azure Kinect / Orbbec Femto .mkv recordings written by Microsoft's own recorder (libk4arecord, through ctypes),
read by tofd; the lens of each depth mode against the SDK's calibration (libk4a's k4a_calibration_get_from_raw
and k4a_calibration_2d_to_3d)."""

from __future__ import annotations

import functools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tofd.algorithm.segmentation import segment
from tofd.config import SegmentationConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.k4a.lens import DEPTH_MODES, depth_lens
from tofd.drivers.k4a.mkv import K4aRecordingError, K4aRecordingSource
from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import iter_frames
from tofd_testing.k4a_helpers import CALIBRATION_JSON, K4A, k4a_libraries
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config, rejected_counters
from tofd_testing.rrd_helpers import foreground_clouds
from tofd_testing.wide_fov import SPHERE_RADIUS_M, sphere_before_wall

ROOT = Path(__file__).resolve().parents[2]
RAW = CALIBRATION_JSON.read_bytes()
SERIAL = "000123456789"
PERIOD_US = 33_333


@pytest.fixture(scope="module")
def k4a() -> K4A:
    return k4a_libraries()


def mode_size(mode: str) -> tuple[int, int]:
    """(H, W) of a depth mode's images."""
    w, h = DEPTH_MODES[mode].output
    return h, w


@functools.cache
def sdk_rays(mode: str) -> np.ndarray:
    """(H, W, 3) the SDK's k4a_calibration_2d_to_3d of every pixel at 1 m depth, in metres (NaN: invalid)."""
    k4a = k4a_libraries()
    h, w = mode_size(mode)
    v, u = np.indices((h, w))
    uv = np.stack([u.ravel(), v.ravel()], axis=-1).astype(np.float64)
    return k4a.unproject(k4a.calibration(RAW, mode), uv, 1000.0).reshape(h, w, 3) / 1000.0


def tofd(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={"RUST_LOG": "error", **__import__("os").environ})


@pytest.mark.parametrize("mode", ["NFOV_2X2BINNED", "NFOV_UNBINNED", "WFOV_2X2BINNED", "WFOV_UNBINNED"])
def test_each_depth_mode_lens_is_the_sdks(k4a, mode):
    cal = k4a.calibration(RAW, mode)
    lens = depth_lens(RAW, mode)
    i = lens.intrinsics
    assert (i.width, i.height) == (cal.depth.resolution_width, cal.depth.resolution_height)
    np.testing.assert_allclose([i.cx, i.cy, i.fx, i.fy], list(cal.depth.parameters)[:4], rtol=0, atol=1e-3)
    # the SDK's rays of a sample of pixels, the corners and the image border included
    h, w = i.shape
    rng = np.random.default_rng(3)
    v, u = rng.integers(0, h, 1500), rng.integers(0, w, 1500)
    edge = np.arange(0, max(h, w), 7)
    u = np.concatenate([u, np.minimum(edge, w - 1), np.zeros_like(edge), np.full_like(edge, w - 1)])
    v = np.concatenate([v, np.zeros_like(edge), np.minimum(edge, h - 1), np.minimum(edge, h - 1)])
    sdk = k4a.unproject(cal, np.stack([u, v], axis=-1).astype(np.float64), 1000.0) / 1000.0
    sdk_valid = np.isfinite(sdk[:, 0])
    np.testing.assert_array_equal(lens.valid_pixels()[v, u], sdk_valid)
    assert sdk_valid.mean() > 0.5
    rays = i.pixel_rays(u, v)
    mine = rays / rays[:, 2:]  # the point at z = 1 m
    np.testing.assert_allclose(mine[sdk_valid], sdk[sdk_valid], rtol=0, atol=2e-5)  # 0.02 mm at 1 m (float32 SDK)
    # and the lens matters: a pinhole with the same fx, fy, cx, cy is metres off... well, centimetres at 1 m
    pinhole = Intrinsics(i.width, i.height, i.fx, i.fy, i.cx, i.cy).pixel_rays(u, v)
    assert np.nanmax(np.abs(pinhole / pinhole[:, 2:] - sdk)[sdk_valid]) > 0.05


def record(k4a: K4A, path: Path, mode: str, depth_mm: list[np.ndarray], ir: list[np.ndarray],
           timestamps_us: list[int]) -> Path:
    return k4a.write_recording(path, mode, depth_mm, ir, timestamps_us, calibration=RAW, serial=SERIAL)


def test_recording_gives_radial_range_ir_amplitude_and_the_devices_clock(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    rng = np.random.default_rng(0)
    depth = [rng.integers(500, 3000, (h, w)).astype(np.uint16) for _ in range(6)]
    for d in depth:
        d[:4, :7] = 0  # no return
    ir = [rng.integers(0, 4000, (h, w)).astype(np.uint16) for _ in range(6)]
    stamps = [7_000_000 + PERIOD_US * n for n in range(6)]
    keep = [0, 1, 2, 4, 5]  # the recorder dropped capture 3
    path = record(k4a, tmp_path / "k.mkv", mode, [depth[n] for n in keep], [ir[n] for n in keep],
                  [stamps[n] for n in keep])
    source = K4aRecordingSource(path)
    frames = list(source)
    assert [f.frame_counter for f in frames] == keep
    assert [(r.frame_counter, r.reason.split(":")[0]) for r in source.take_rejected()] == [(3, "damaged")]
    assert source.stopped_reason == "end" and source.fps == pytest.approx(1e6 / PERIOD_US, rel=1e-4)
    lens = depth_lens(RAW, mode)
    rays = sdk_rays(mode)
    for f, n in zip(frames, keep, strict=True):
        assert f.timestamp_us == stamps[n] and f.intrinsics == lens.intrinsics
        np.testing.assert_array_equal(f.amplitude, ir[n].astype(np.float32))
        z = depth[n] / 1000.0
        expected = z * np.linalg.norm(rays, axis=-1)  # the SDK's point at that depth, its distance from the camera
        assert np.all(np.isnan(f.range_m[:4, :7]))
        valid = depth[n] > 0
        np.testing.assert_allclose(f.range_m[valid], expected[valid], rtol=2e-6, atol=2e-6)
    assert frames[0].device.serial == SERIAL and frames[0].device.model == "Azure Kinect"
    assert frames[1].host_wall_s - frames[0].host_wall_s == pytest.approx(PERIOD_US / 1e6, abs=1e-6)


def test_frames_carry_the_recordings_settings_not_sr3000_registers_through_import_and_replay(k4a, tmp_path):
    """No SR3000 register map: registers None and a SensorInfo from the file (millimetres, 0 invalid, 16-bit IR,
    the period of the device timestamps, the K4A_* tags); `tofd import` keeps it in the recording's header and
    in every frame, with the camera's identity."""
    mode = "WFOV_2X2BINNED"
    h, w = mode_size(mode)
    rng = np.random.default_rng(1)
    depth = [rng.integers(0, 2500, (h, w)).astype(np.uint16) for _ in range(4)]
    ir = [rng.integers(0, 60000, (h, w)).astype(np.uint16) for _ in range(4)]
    stamps = [1_000_000 + PERIOD_US * n for n in range(4)]
    path = record(k4a, tmp_path / "k.mkv", mode, depth, ir, stamps)
    frames = list(K4aRecordingSource(path))
    sensor = frames[0].sensor
    assert sensor is not None and all(f.registers is None and f.sensor == sensor for f in frames)
    assert (sensor.depth_unit_m, sensor.invalid_value, sensor.amplitude, sensor.amplitude_full_scale) == \
        (1e-3, 0, "ir", 65535.0)
    assert sensor.frame_period_s == pytest.approx(PERIOD_US / 1e6) and sensor.unambiguous_range_m is None
    assert sensor.settings["K4A_DEPTH_MODE"] == mode and sensor.settings["K4A_DEVICE_SERIAL_NUMBER"] == SERIAL
    assert all(key.startswith("K4A_") for key in sensor.settings)
    out = tmp_path / "k.mcap"
    proc = tofd("import", path, out)
    assert proc.returncode == 0, proc.stderr
    info = read_recording_info(out)
    assert (info.registers, info.sensor) == (None, sensor)
    assert (info.device.model, info.device.serial, info.device.backend) == ("Azure Kinect", SERIAL, "k4a-mkv")
    replayed = list(iter_frames(out))
    assert [f.frame_counter for f in replayed] == [f.frame_counter for f in frames]
    for got, want in zip(replayed, frames, strict=True):
        assert got.registers is None and got.sensor == sensor and got.device == want.device
        np.testing.assert_array_equal(got.amplitude, want.amplitude)


def test_a_damaged_recording_gives_its_intact_captures_and_ledgers_the_rest(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    n = 16
    depth = [np.full((h, w), 900 + k, np.uint16) for k in range(n)]
    ir = [np.full((h, w), 100 + k, np.uint16) for k in range(n)]
    path = record(k4a, tmp_path / "k.mkv", mode, depth, ir, [3_000_000 + PERIOD_US * k for k in range(n)])
    data = path.read_bytes()

    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) * 6 // 10])
    source = K4aRecordingSource(cut)
    got = [f.frame_counter for f in source]
    assert got == list(range(len(got))) and 5 <= len(got) < n
    assert rejected_counters(source) == list(range(len(got), n))
    assert source.stopped_reason == "truncated" and source.last_good_counter == len(got) - 1

    garbled = tmp_path / "garbled.mkv"
    start, stop = len(data) // 2, len(data) // 2 + 2 * h * w * 2
    garbled.write_bytes(data[:start] + np.random.default_rng(1).bytes(stop - start) + data[stop:])
    source = K4aRecordingSource(garbled)
    frames = list(source)
    lost = rejected_counters(source)
    assert lost and sorted([f.frame_counter for f in frames] + lost) == list(range(n))
    assert source.stopped_reason == "end"
    # Matroska blocks carry no checksum: a block whose pixels (not its framing) were hit cannot be told from an
    # intact one; every frame whose blocks lie outside the damaged bytes is delivered as recorded
    for f in frames:
        k = f.frame_counter
        spans = [(data.find(plane[k].astype(">u2").tobytes()), h * w * 2) for plane in (depth, ir)]
        if all(0 <= at and (at + size <= start or at >= stop) for at, size in spans):
            assert np.all(f.amplitude == 100 + k)
            np.testing.assert_allclose(f.range_m * depth_lens(RAW, mode).intrinsics.unit_rays()[..., 2],
                                       (900 + k) / 1000, rtol=1e-6)
    assert sum(1 for f in frames if np.all(f.amplitude == 100 + f.frame_counter)) >= n - len(lost) - 2


def test_imu_and_colour_tracks_leave_the_recording_intact(k4a, tmp_path):
    """k4arecorder's IMU track (1.6 kHz, running on past the last capture) and colour captures before, between
    and after the depth captures: tofd reads every depth capture Microsoft's playback reads, at the same device
    times; `tofd info` finds no damage, `tofd replay` drops nothing, `tofd batch` over the folder succeeds. The
    same file cut short is still truncated."""
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    n = 12
    stamps = [5_000_000 + PERIOD_US * k for k in range(n)]
    depth = [np.full((h, w), 900 + k, np.uint16) for k in range(n)]
    ir = [np.full((h, w), 100 + k, np.uint16) for k in range(n)]
    colour = [stamps[0] - 20_000, stamps[3], *(t + 11_000 for t in stamps), stamps[-1] + 45_000, stamps[-1] + 90_000]
    folder = tmp_path / "recordings"
    folder.mkdir()
    paths = {name: k4a.write_recording(folder / f"{name}.mkv", mode, depth, ir, stamps, calibration=RAW, serial=SERIAL,
                                       **kw)
             for name, kw in (("imu", {"imu": True}), ("colour", {"colour_us": colour}),
                              ("both", {"imu": True, "colour_us": colour}))}
    for name, path in paths.items():
        assert k4a.playback_depth_times(path) == stamps, name
        source = K4aRecordingSource(path)
        frames = list(source)
        assert [f.timestamp_us for f in frames] == stamps and [f.frame_counter for f in frames] == list(range(n))
        assert source.take_rejected() == [] and source.stopped_reason == "end", (name, source.stop_detail)
        assert [int(f.amplitude[0, 0]) for f in frames] == [100 + k for k in range(n)]
    proc = tofd("info", "--json", paths["both"])
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["frames"] == n and info["damage"] == {"rejected": {}, "stopped": None}, info["damage"]
    lens = depth_lens(RAW, mode).intrinsics  # the lens and the depth unit, as `tofd info` shows them
    assert info["lens"] == {"model": "rational_polynomial", "coefficients": dict(
        zip(("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), lens.distortion, strict=True))}
    assert info["depth_unit_m"] == 1e-3
    text = dict(line.split(":", 1) for line in tofd("info", paths["both"]).stdout.splitlines())
    assert text["lens"].strip().startswith("rational_polynomial (Brown-Conrady") and \
        f"k4 {lens.distortion[5]:.6g}," in text["lens"]
    assert text["depth unit"].strip() == "0.001 m per raw value" and text["damage"].strip() == "none found"
    proc = tofd("replay", paths["both"], "--out", tmp_path / "out", "--rerun", "none")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "out" / "both.summary.json").read_text())
    assert (summary["frames_in"], summary["frames_out"], summary["frames_dropped"]) == (n, n, 0), summary["drops"]
    proc = tofd("batch", folder, "--out", tmp_path / "batch", "--workers", "1", "--no-evaluation")
    assert proc.returncode == 0, proc.stderr
    batch = json.loads((tmp_path / "batch" / "_summary.json").read_text())
    assert batch["frames_in"] == batch["frames_out"] == 3 * n and batch["frames_dropped"] == 0
    # the whole file's IMU blocks reach its segment duration; cut short, it is truncated as before
    data = paths["both"].read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) * 6 // 10])
    source = K4aRecordingSource(cut)
    got = [f.frame_counter for f in source]
    assert 3 <= len(got) < n and source.stopped_reason == "truncated"
    lost = rejected_counters(source)
    # counted up to the segment's end: a cut file cannot say that its depth track ended before the IMU's
    assert lost == list(range(len(got), lost[-1] + 1)) and lost[-1] >= n - 1


@pytest.mark.slow
def test_wfov_recording_segments_the_near_sphere_in_every_frame(k4a, tmp_path):
    """A WFOV_2X2BINNED recording by libk4arecord (sphere 20 degrees off axis at 0.85-0.95 m, wall at 1.6 m, the
    lens's dark corners as the device writes them, z-depth in millimetres): tofd's foreground of every frame it
    reads is on the sphere, and so is the 3-D foreground `tofd replay` logs for each of the 30 frames."""
    mode = "WFOV_2X2BINNED"
    lens = depth_lens(RAW, mode)
    ray_z = lens.intrinsics.unit_rays()[..., 2]
    scenes = [sphere_before_wall(lens.intrinsics, float(d), 90.0 * (k % 4), lens.valid_pixels())
              for k, d in enumerate(np.linspace(0.85, 0.95, 30))]
    depth = [np.nan_to_num(np.rint(s.range_m * ray_z * 1000), nan=0).astype(np.uint16) for s in scenes]
    ir = [np.clip(s.amplitude, 0, 65535).astype(np.uint16) for s in scenes]
    path = record(k4a, tmp_path / "wfov.mkv", mode, depth, ir, [1_000_000 + PERIOD_US * k for k in range(30)])
    frames = list(K4aRecordingSource(path))
    assert len(frames) == 30
    for frame, scene in zip(frames, scenes, strict=True):
        mask = segment(frame.range_m, frame.amplitude, SegmentationConfig(), frame.intrinsics)
        assert mask.sum() > 0.2 * scene.sphere.sum() and not (mask & ~scene.sphere).any(), frame.frame_counter
    out = tmp_path / "out"
    proc = tofd("replay", path, "--out", out, "--config",
                bundled_config(tmp_path / "tofd.toml", pipeline=PATIENT_VIEWER))
    assert proc.returncode == 0, proc.stderr
    clouds = foreground_clouds(out / "wfov.rrd")
    assert len(clouds) == 30
    for points, scene in zip(clouds, scenes, strict=True):
        off = np.abs(np.linalg.norm(points - scene.centre, axis=1) - SPHERE_RADIUS_M)
        assert len(points) > 100 and np.median(off) < 0.002 and off.max() < 0.01, (np.median(off), off.max())


def test_unreadable_recordings_are_one_line_and_exit_2(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    plane = np.full((h, w), 1000, np.uint16)
    uncalibrated = k4a.write_recording(tmp_path / "uncalibrated.mkv", mode, [plane], [plane], [1_000_000])
    garbage = tmp_path / "garbage.mkv"
    garbage.write_bytes(b"\x1a\x45\xdf\xa3" + bytes(range(256)) * 8)
    unknown = tmp_path / "notes.mcap"
    unknown.write_text("hello")
    for path, words in ((uncalibrated, ["uncalibrated.mkv", "attachment calibration.json", "missing"]),
                        (garbage, ["garbage.mkv", "not a readable Matroska file"]),
                        (unknown, ["notes.mcap", "not a recording tofd reads", "Azure Kinect"])):
        proc = tofd("replay", path, "--out", tmp_path / "out", "--rerun", "none")
        err = proc.stderr.strip()
        assert proc.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert all(word in err for word in words), (words, err)
    with pytest.raises(K4aRecordingError, match="attachment calibration.json"):
        K4aRecordingSource(uncalibrated)


def render_scene(mode: str, sphere_px: tuple[int, int], distance_m: float, radius_m: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """uint16 z-depth (mm) and IR (1 / range^2) of a bright sphere (centre on the SDK's ray of pixel sphere_px,
    distance_m away) before a dark plane tilted 20 degrees about the x axis, seen through the SDK's lens; and the
    sphere's centre."""
    rays = sdk_rays(mode)  # (x, y, 1): z = 1
    centre = distance_m * rays[sphere_px[1], sphere_px[0]] / np.linalg.norm(rays[sphere_px[1], sphere_px[0]])
    dd = np.einsum("ijk,ijk->ij", rays, rays)
    dc = rays @ centre
    disc = dc * dc - dd * (centre @ centre - radius_m ** 2)
    with np.errstate(invalid="ignore"):
        t_sphere = np.where(disc >= 0, (dc - np.sqrt(disc)) / dd, np.inf)
        normal = np.array([0.0, -np.sin(np.radians(20)), np.cos(np.radians(20))])
        t_plane = 1.4 * normal[2] / (rays @ normal)
        z = np.fmin(t_sphere, np.where(t_plane > 0, t_plane, np.inf))
        depth = np.where(np.isfinite(z), np.rint(z * 1000), 0).astype(np.uint16)
        albedo = np.where(t_sphere <= z, 1.0, 0.15)  # a bright ball before a dark wall
        ir = np.where(depth > 0, np.clip(albedo * 4000 * (0.5 / (z * np.sqrt(dd))) ** 2, 0, 65535), 0)
    return depth, ir.astype(np.uint16), centre


@pytest.mark.slow
# sphere centres 40 and 45 degrees off axis, where a pinhole misplaces the pixel by 72 and 56 px
@pytest.mark.parametrize(("mode", "sphere_px"), [("NFOV_UNBINNED", (100, 90)), ("WFOV_2X2BINNED", (130, 120))])
def test_a_sphere_in_the_distorted_corner_comes_back_on_the_sphere(k4a, tmp_path, mode, sphere_px):
    radius = 0.10
    depth, ir, centre = render_scene(mode, sphere_px, 0.65, radius)
    path = record(k4a, tmp_path / "sphere.mkv", mode, [depth] * 3, [ir] * 3,
                  [4_000_000 + PERIOD_US * k for k in range(3)])
    out = tmp_path / "out"
    proc = tofd("replay", path, "--out", out, "--config",
                bundled_config(tmp_path / "tofd.toml", pipeline=PATIENT_VIEWER))
    assert proc.returncode == 0, proc.stderr
    clouds = foreground_clouds(out / "sphere.rrd")
    assert len(clouds) == 3 and all(len(c) > 500 for c in clouds)
    points = np.concatenate(clouds)
    off = np.abs(np.linalg.norm(points - centre, axis=1) - radius)
    assert np.median(off) < 0.002 and np.percentile(off, 90) < 0.005, (np.median(off), np.percentile(off, 90))
    # the plane behind, in every corner, through tofd's frames
    frame = next(iter(K4aRecordingSource(path)))
    xyz = frame.intrinsics.backproject(frame.range_m)
    normal = np.array([0.0, -np.sin(np.radians(20)), np.cos(np.radians(20))])
    on_plane = np.isfinite(frame.range_m) & (np.linalg.norm(xyz - centre, axis=-1) > radius + 0.01)
    h, w = frame.range_m.shape
    for rows, cols in ((slice(0, h // 4), slice(0, w // 4)), (slice(0, h // 4), slice(-w // 4, None)),
                       (slice(-h // 4, None), slice(0, w // 4)), (slice(-h // 4, None), slice(-w // 4, None))):
        corner = on_plane[rows, cols]
        if corner.sum() < 50:
            continue
        err = np.abs(xyz[rows, cols][corner] @ normal - 1.4 * normal[2])
        assert np.median(err) < 0.002 and np.percentile(err, 90) < 0.005
    # a pinhole with the same focal lengths and centre puts that sphere centimetres away
    pinhole = Intrinsics(w, h, frame.intrinsics.fx, frame.intrinsics.fy, frame.intrinsics.cx, frame.intrinsics.cy)
    sphere = np.isfinite(frame.range_m) & (np.abs(np.linalg.norm(xyz - centre, axis=-1) - radius) < 0.005)
    wrong = pinhole.backproject(frame.range_m)[sphere]
    assert np.median(np.abs(np.linalg.norm(wrong - centre, axis=1) - radius)) > 0.01


def _cluster_starts(data: bytes) -> list[int]:
    """Byte offsets of the Matroska Cluster elements (ID 1F 43 B6 75) of a recording."""
    starts, at = [], data.find(b"\x1f\x43\xb6\x75")
    while at >= 0:
        starts.append(at)
        at = data.find(b"\x1f\x43\xb6\x75", at + 1)
    return starts


def test_a_damaged_first_cluster_is_counted_lost_or_is_nothing_readable(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    n = 8
    path = record(k4a, tmp_path / "k.mkv", mode, [np.full((h, w), 900 + k, np.uint16) for k in range(n)],
                  [np.full((h, w), 100 + k, np.uint16) for k in range(n)],
                  [5_000_000 + PERIOD_US * k for k in range(n)])
    data = path.read_bytes()
    first, second = _cluster_starts(data)[:2]

    garbled = tmp_path / "garbled.mkv"  # the first cluster's blocks unreadable, its framing kept
    garbled.write_bytes(data[:first + 4] + np.random.default_rng(2).bytes(second - first - 4) + data[second:])
    source = K4aRecordingSource(garbled)
    frames = list(source)
    lost = rejected_counters(source)
    assert sorted([f.frame_counter for f in frames] + lost) == list(range(n)) and lost[0] == 0
    assert all(np.all(f.amplitude == 100 + f.frame_counter) for f in frames)  # counted from the recording's start

    unreadable = tmp_path / "unreadable.mkv"  # the first cluster's ID gone: the demuxer reads no block at all
    unreadable.write_bytes(data[:first] + bytes(4) + data[first + 4:])
    with pytest.raises(K4aRecordingError, match="nothing readable"):
        K4aRecordingSource(unreadable)
    proc = tofd("info", unreadable)
    assert proc.returncode == 2 and "nothing readable" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_a_long_capture_gap_is_one_rejected_range(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    stamps = [1_000_000 + PERIOD_US * k for k in range(10)] + [1_000_000 + PERIOD_US * 90_000]
    path = record(k4a, tmp_path / "k.mkv", mode, [np.full((h, w), 900, np.uint16)] * 11,
                  [np.full((h, w), 100, np.uint16)] * 11, stamps)
    source = K4aRecordingSource(path)
    assert [f.frame_counter for f in source] == [*range(10), 90_000]
    (gap,) = source.take_rejected()
    assert (gap.frame_counter, gap.frames) == (10, 90_000 - 10) and gap.reason.startswith("damaged: no capture from")


def test_an_oversized_or_unusable_calibration_attachment_is_refused_in_one_line(k4a, tmp_path):
    mode = "NFOV_2X2BINNED"
    h, w = mode_size(mode)
    planes = [np.full((h, w), 900, np.uint16)] * 2
    big = k4a.write_recording(tmp_path / "big.mkv", mode, planes, planes, [0, PERIOD_US],
                              calibration=RAW + b" " * (2 << 20), serial=SERIAL)
    with pytest.raises(K4aRecordingError, match="attachment calibration.json: .* bytes, more than a device"):
        K4aRecordingSource(big)
    calibration = json.loads(RAW)
    cameras = calibration["CalibrationInformation"]["Cameras"]
    depth = next(c for c in cameras if c["Location"] == "CALIBRATION_CameraLocationD0")
    depth["Intrinsics"]["ModelParameters"][2] = 1e-300  # fx
    tiny = k4a.write_recording(tmp_path / "tiny.mkv", mode, planes, planes, [0, PERIOD_US],
                               calibration=json.dumps(calibration).encode(), serial=SERIAL)
    nested = k4a.write_recording(tmp_path / "nested.mkv", mode, planes, planes, [0, PERIOD_US],
                                 calibration=b"[" * 100_000 + b"]" * 100_000, serial=SERIAL)
    for path, why in ((tiny, "fx: expected a finite focal length"), (nested, "nested too deeply")):
        proc = tofd("info", path)
        assert proc.returncode == 2 and why in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
