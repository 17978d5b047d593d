"""Rerun sink: every delivered frame's entities arrive in the .rrd (read back with Rerun's own reader)."""

import json

import pytest
from rerun.chunk import RrdReader

from tofd.algorithm.segmentation import foreground_box
from tofd.config import Config
from tofd.service.pipeline import Pipeline
from tofd.service.viewer import RerunLogger, RerunTarget
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.logger import frames_per_send
from tofd_testing.pipeline_sources import RenderedSource
from tofd_testing.rrd_helpers import check_rrd


@pytest.mark.slow
@pytest.mark.parametrize("batch_frames", [1, 4])
def test_saved_rrd_holds_every_frame(tmp_path, batch_frames):
    """Sent frame by frame or 4 at a time (19 frames: the last batch is partial, sent when the sink ends)."""
    cfg = Config()
    path = tmp_path / "run.rrd"
    target = RerunTarget(cfg.rerun, "save", cfg.intrinsics.shape, path=str(path))
    kept = {}
    logger = RerunLogger(target.rec, cfg.intrinsics, batch_frames=batch_frames)
    pipeline = Pipeline(cfg, "lossless", inline_viewer=logger,
                        writers=(lambda r: kept.__setitem__(r.frame.frame_counter, r),))
    source = RenderedSource(20, skip_counters=(7,), n_distinct=3)
    pipeline.start(source)
    assert pipeline.wait(60)
    summary = pipeline.close()
    target.close()
    assert summary["frames_out"] == 19 and summary["consistent"]
    tables = check_rrd(path, source.emitted, kept)
    events = tables[bp.EVENTS][1]
    assert events.column("frame").to_pylist() == [8]
    assert "counter_gap" in events.column("TextLog:text")[0].as_py()[0]
    assert RrdReader(str(path)).blueprints(), "the blueprint is stored with the recording"


@pytest.mark.slow
def test_a_batch_is_sent_once_its_first_frame_waited_long_enough(tmp_path):
    """However large the batch, a frame reaches the stream within MAX_BATCH_AGE_S of the next one (slow replay)."""
    import time

    import rerun as rr

    from tofd.service.viewer.logger import MAX_BATCH_AGE_S
    from tofd_testing.rrd_helpers import read_entities

    kept = []
    pipeline = Pipeline(Config(), "lossless", writers=(kept.append,))
    pipeline.start(RenderedSource(3, n_distinct=1))
    assert pipeline.wait(60)
    pipeline.close()
    rec = rr.RecordingStream("tofd-test")
    rec.save(str(tmp_path / "slow.rrd"))
    logger = RerunLogger(rec, Config().intrinsics, batch_frames=100)
    logger(kept[0])
    logger(kept[1])
    assert logger.pending == 2
    time.sleep(MAX_BATCH_AGE_S)
    logger(kept[2])
    assert logger.pending == 0
    rec.flush()
    rec.disconnect()
    ranges = read_entities(str(tmp_path / "slow.rrd"))[bp.RANGE][1]
    assert ranges.column("frame").to_pylist() == [r.frame.frame_counter for r in kept]


def test_bad_sink_is_rejected():
    with pytest.raises(ValueError, match="sink"):
        RerunTarget(Config().rerun, "telepathy", Config().intrinsics.shape)


def test_results_lines_match_delivered_frames(tmp_path):
    from tofd.service.pipeline import ResultsWriter

    writer = ResultsWriter(tmp_path / "r.jsonl")
    pipeline = Pipeline(Config(), "lossless", writers=(writer,))
    pipeline.start(RenderedSource(6, n_distinct=2))
    assert pipeline.wait(60)
    pipeline.close()
    writer.close()
    lines = [json.loads(x) for x in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert [x["frame_counter"] for x in lines] == list(range(6))
    assert all(x["timings_ms"]["nfft"] > 0 and x["ground_truth_px"] is not None for x in lines)


def test_depth_image_under_the_pinhole_projects_a_plane_to_its_true_3d_points(tmp_path):
    """A fronto-parallel wall at z = 0.8 m: every pixel of the logged DepthImage, back-projected with the logged
    Pinhole the way Rerun's 3-D view does (x = (u + 0.5 - px) / fx * d), lands on the wall; the radial range is
    not logged twice and the amplitude's scale is recorded."""
    import numpy as np
    import rerun as rr

    from tofd.drivers.frame import Frame
    from tofd.drivers.intrinsics import Intrinsics
    from tofd.service.pipeline.results import FrameResult
    from tofd_testing.rrd_helpers import amplitude_at, feature_crop_at, feature_map_at, image_at, read_entities

    intr = Intrinsics()
    rays = intr.unit_rays()
    radial = (0.8 / rays[..., 2]).astype(np.float32)  # the camera measures along each ray
    amplitude = np.full(intr.shape, 1234.4, np.float32)
    frame = Frame(radial, amplitude, frame_counter=5, timestamp_us=1000, host_monotonic_s=0.0, host_wall_s=0.0)
    mask = np.zeros(intr.shape, bool)
    feats = {name: np.full(intr.shape, np.nan, np.float32) for name in bp.FEATURES}
    rec = rr.RecordingStream("tofd-test")
    path = tmp_path / "plane.rrd"
    rec.save(str(path))
    result = FrameResult(0, frame, mask, feats, 0, 0.0, arrival_s=0.0, box=foreground_box(mask))
    RerunLogger(rec, intr, point_cloud=False)(result)
    rec.flush()
    rec.disconnect()
    tables = read_entities(str(path))
    depth = image_at(tables[bp.RANGE][1], "DepthImage", 0)
    pinhole = tables[bp.CAMERA][0][0].to_record_batch()
    matrix = np.array(pinhole.column("Pinhole:image_from_camera")[0].as_py()[0]).reshape(3, 3).T  # column-major
    fx, fy, px, py = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    for v, u in ((0, 0), (0, 175), (143, 0), (72, 88), (143, 175)):
        d = float(depth[v, u])
        point = np.array([(u + 0.5 - px) / fx * d, (v + 0.5 - py) / fy * d, d])
        assert point[2] == pytest.approx(0.8, abs=1e-6)
        np.testing.assert_allclose(point, rays[v, u] * radial[v, u], atol=1e-5)  # the camera's own 3-D point
    assert float(radial[0, 0]) > 0.8 * 1.1  # a corner: the radial range would be > 10 % off as depth
    assert not [e for e in tables if e.endswith("/range")]  # radial = depth / ray z
    amp, scale = amplitude_at(tables, 0)  # uniform: its top is the brightest level, the scale recorded
    assert amp.dtype == np.uint8 and np.all(amp == 255) and scale * 255 == pytest.approx(1234.4)
    for entity in bp.FEATURES.values():  # no foreground: nothing drawn, from a one-pixel crop
        assert not feature_map_at(tables[entity][1], 0, intr.shape).any()
        assert feature_crop_at(tables[entity][1], 0)[0].shape == (1, 1)


def test_blueprint_has_an_events_view():
    import rerun.blueprint as rrb

    from tofd.service.viewer import build_blueprint

    def views(container):
        for item in getattr(container, "contents", []) or []:
            yield item
            yield from views(item)

    found = [v for v in views(build_blueprint((144, 176)).root_container) if isinstance(v, rrb.TextLogView)]
    assert [v.origin for v in found] == [bp.EVENTS]


@pytest.mark.slow
def test_saved_rrd_is_batched_and_the_viewer_sends_no_usage_data(tmp_path, monkeypatch):
    """`rerun rrd stats` does not call a saved replay "unoptimized"; with [rerun] analytics = false (default) the
    rerun binary we start sees CI=1 and has analytics off (it prints no opt-in banner and no config)."""
    import os
    import subprocess

    from tofd.service.viewer.targets import rerun_executable

    monkeypatch.delenv("CI", raising=False)
    cfg = Config()
    path = tmp_path / "run.rrd"
    target = RerunTarget(cfg.rerun, "save", cfg.intrinsics.shape, path=str(path))
    assert os.environ.get("CI") == "1"
    logger = RerunLogger(target.rec, cfg.intrinsics, batch_frames=frames_per_send(cfg.rerun, "lossless"))
    pipeline = Pipeline(cfg, "lossless", inline_viewer=logger)
    pipeline.start(RenderedSource(60, n_distinct=3))
    assert pipeline.wait(120)
    pipeline.close()
    target.close()
    stats = subprocess.run([rerun_executable(), "rrd", "stats", str(path)], capture_output=True, text=True,
                           timeout=120, env={**os.environ, "RUST_LOG": "error"})
    assert "theoretical lower bound" in stats.stdout + stats.stderr
    assert "may be unoptimized" not in stats.stdout + stats.stderr
    home = tmp_path / "home"
    home.mkdir()
    details = subprocess.run([rerun_executable(), "analytics", "config"], capture_output=True, text=True,
                             timeout=60, env={**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": str(home)})
    assert details.stdout.strip() == "null" and "Welcome to Rerun" not in details.stdout


def _log_one(tmp_path, frame, mask):
    """Log one FrameResult of `frame` (feature maps 1.0 on the mask) to an .rrd; its entity tables."""
    import numpy as np
    import rerun as rr

    from tofd.service.pipeline.results import FrameResult
    from tofd_testing.rrd_helpers import read_entities

    feats = {name: np.where(mask, np.float32(1.0), np.float32(np.nan)) for name in bp.FEATURES}
    rec = rr.RecordingStream("tofd-test")
    path = tmp_path / "one.rrd"
    rec.save(str(path))
    result = FrameResult(0, frame, mask, feats, 0, 0.0, arrival_s=0.0, box=foreground_box(mask))
    RerunLogger(rec, frame.intrinsics)(result)
    rec.flush()
    rec.disconnect()
    return read_entities(str(path))


def test_millimetre_depth_is_stored_as_the_sources_integers_and_lines_up_with_the_cloud(tmp_path):
    """A 640x576 camera giving z-depth in whole millimetres (a slanted wall, as the Azure Kinect driver converts
    it to radial range): the .rrd holds a 16-bit PNG of exactly those millimetres with meter 1000, whose pixels
    back-projected through the Pinhole are the camera's own 3-D points, and the foreground cloud's points lie on
    the depth image's (the 3-D view and the image agree)."""
    import numpy as np

    from tofd.drivers.frame import Frame, SensorInfo
    from tofd.lab.cameras import CAMERAS
    from tofd.service.viewer.pixels import CLOUD_POINTS, cloud_pixels
    from tofd_testing.rrd_helpers import amplitude_at, check_amplitude, depth_at, image_at, mask_at

    intr = CAMERAS["k4a-nfov"]
    v, u = np.indices(intr.shape)
    z_mm = (700 + u // 3 + v // 5).astype(np.uint16)
    z_mm[:20, :30] = 0  # no return
    rays = intr.unit_rays()
    scale = np.float32(1e-3) / rays[..., 2].astype(np.float32)  # the K4A driver's mm -> radial metres
    radial = np.where(z_mm > 0, z_mm * scale, np.nan).astype(np.float32)
    bright = 100 + 3000 * np.exp(-((u - 320) ** 2 + (v - 288) ** 2) / 200**2)  # an IR image: lit in the middle
    amplitude = (bright * np.random.default_rng(0).normal(1, 0.02, intr.shape)).astype(np.float32)  # 2 % noise
    frame = Frame(radial, amplitude, frame_counter=0, timestamp_us=0, host_monotonic_s=0.0, host_wall_s=0.0,
                  intrinsics=intr, sensor=SensorInfo(depth_unit_m=1e-3, amplitude="ir"))
    mask = np.zeros(intr.shape, bool)
    mask[200:400, 250:450] = True  # 40000 pixels: more than a cloud holds
    tables = _log_one(tmp_path, frame, mask)
    depth_m, stored = depth_at(tables, 0)
    assert stored.dtype == np.uint16
    np.testing.assert_array_equal(stored, z_mm)  # exactly the source's millimetres
    check_amplitude(*amplitude_at(tables, 0), amplitude)  # for viewing: 8 bits at the recorded scale
    np.testing.assert_array_equal(mask_at(tables[bp.MASK][1], 0, intr.shape), mask)  # its box, put in place
    assert image_at(tables[bp.MASK][1], "SegmentationImage", 0).shape == (200, 200)
    pinhole = tables[bp.CAMERA][0][0].to_record_batch()
    matrix = np.array(pinhole.column("Pinhole:image_from_camera")[0].as_py()[0]).reshape(3, 3).T
    fx, fy, px, py = matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2]
    xyz = np.stack([(u + 0.5 - px) / fx * depth_m, (v + 0.5 - py) / fy * depth_m, depth_m], axis=-1)
    valid = z_mm > 0
    np.testing.assert_allclose(xyz[valid], (rays * radial[..., None])[valid], atol=1e-6)
    cloud = np.asarray(tables[bp.FOREGROUND][1].column("Points3D:positions")[0].as_py(), np.float64)
    at = cloud_pixels(mask)
    assert len(cloud) == len(at) <= CLOUD_POINTS and len(at) > CLOUD_POINTS / 4  # an even subsample
    np.testing.assert_allclose(cloud, xyz.reshape(-1, 3)[at], atol=1e-6)


def test_depth_that_is_not_whole_units_of_its_source_goes_as_float_metres(tmp_path):
    """A source claiming millimetres whose ranges are not whole millimetres of z-depth: the depth goes as float32
    metres, the exact z-depth of the range."""
    import numpy as np

    from tofd.drivers.frame import Frame, SensorInfo
    from tofd.drivers.intrinsics import Intrinsics
    from tofd_testing.rrd_helpers import depth_at

    intr = Intrinsics()
    radial = np.random.default_rng(0).uniform(0.5, 1.5, intr.shape).astype(np.float32)
    frame = Frame(radial, np.ones(intr.shape, np.float32), frame_counter=0, timestamp_us=0, host_monotonic_s=0.0,
                  host_wall_s=0.0, intrinsics=intr, sensor=SensorInfo(depth_unit_m=1e-3, amplitude="ir"))
    tables = _log_one(tmp_path, frame, np.zeros(intr.shape, bool))
    depth_m, stored = depth_at(tables, 0)
    assert stored.dtype == np.float32
    np.testing.assert_array_equal(stored, radial * intr.unit_rays().astype(np.float32)[..., 2])


def test_sr3000_depth_is_z_in_its_range_code_within_half_a_code(tmp_path):
    """The SR3000 measures radial range in whole codes (c / (2 f) / 65535): its z-depth goes as raw uint16 in that
    code (meter: codes per metre), every pixel within half a code of the exact z-depth, and back-projected through
    the Pinhole onto the camera's own 3-D points as closely; no return (0xFFFF: NaN) is 0."""
    import numpy as np

    from tofd.drivers import sr3000
    from tofd.drivers.frame import Frame, Registers
    from tofd.drivers.intrinsics import Intrinsics
    from tofd_testing.rrd_helpers import depth_at, image_at, static_value

    intr, registers = Intrinsics(), Registers()
    raw = np.random.default_rng(3).integers(3000, 60000, intr.shape).astype(np.uint16)
    radial = sr3000.raw_to_range_m(raw, sr3000.mod_freq_khz(registers.mod_freq_index))
    radial[:5, :7] = np.nan
    frame = Frame(radial, np.ones(intr.shape, np.float32), frame_counter=0, timestamp_us=0, host_monotonic_s=0.0,
                  host_wall_s=0.0, intrinsics=intr, registers=registers)
    tables = _log_one(tmp_path, frame, np.zeros(intr.shape, bool))
    code = sr3000.non_ambiguity_range_m(sr3000.mod_freq_khz(registers.mod_freq_index)) / 65535
    assert static_value(tables, bp.RANGE, "DepthImage:meter") == pytest.approx(1 / code, rel=1e-6)
    depth_m, stored = depth_at(tables, 0)
    assert stored.dtype == np.uint16 and stored.shape == intr.shape
    assert image_at(tables[bp.RANGE][1], "DepthImage", 0).dtype == np.uint16  # raw, not a PNG
    rays = intr.unit_rays()
    z_m = np.nan_to_num(radial.astype(np.float64) * rays[..., 2])
    error = np.abs(depth_m - z_m)
    assert 0.3 * code < error.max() <= 0.52 * code  # rounded to codes (and float32 round-off at up to 6e4 codes)
    assert not stored[:5, :7].any() and stored[5:, 7:].all()
    points = depth_m[..., None] * rays / rays[..., 2:]  # the 3-D view's back-projection of a z-depth
    np.testing.assert_allclose(points[5:, 7:], (radial[..., None] * rays)[5:, 7:], rtol=0, atol=code)
