"""The nose track reported beside the per-frame detection: results records, the run's track counts, the viewer's
wire format and its Rerun entities (read back from a real .rrd), and /metrics of a live run with a model."""

from __future__ import annotations

import json
import math
import time
import urllib.request

import numpy as np
import pytest

from tests.service.test_health import metric_values
from tofd.algorithm.detector import Detection
from tofd.algorithm.names import MAP_NAMES
from tofd.algorithm.segmentation import foreground_box
from tofd.algorithm.tracking import NoseTracker, TrackerConfig
from tofd.batch.rows import frame_row
from tofd.config import Config, load_config
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.service.health import HealthServer, ServiceMetrics
from tofd.service.model import load_service_model
from tofd.service.pipeline import Pipeline
from tofd.service.pipeline.results import FrameResult, result_record, track_from, track_px
from tofd.service.pipeline.slots import SlotRing
from tofd.service.pipeline.stats import TrackSnapshot, TrackStats
from tofd.service.viewer import RerunLogger, RerunTarget, wire
from tofd.service.viewer import blueprint as bp
from tofd_testing.pipeline_sources import RenderedSource, write_config
from tofd_testing.rrd_helpers import read_entities

INTRINSICS = Intrinsics()
DT = 0.04


def hit(x: float, z: float = 0.5) -> Detection:
    return Detection((0, 0), (x, 0.0, z), 0.1, True)


MISS = Detection(None, None, 3.0, False)


def result(counter: int, detection: Detection, track) -> FrameResult:
    """A FrameResult of a flat 0.5 m frame with every map NaN, carrying `detection` and `track`."""
    shape = INTRINSICS.shape
    frame = Frame(np.full(shape, 0.5, np.float32), np.full(shape, 100.0, np.float32), counter,
                  timestamp_us=int(counter * DT * 1e6), host_monotonic_s=time.monotonic(), host_wall_s=0.0,
                  intrinsics=INTRINSICS)
    return FrameResult(seq=counter, frame=frame, mask=np.zeros(shape, bool),
                       features={n: np.full(shape, np.nan, np.float32) for n in MAP_NAMES}, nfft_iterations=3,
                       nfft_residual=1e-3, arrival_s=time.monotonic(), box=(slice(0, 0), slice(0, 0)),
                       detection=detection, track=track)


def tracked_results(detections: list[Detection], cfg: TrackerConfig | None = None) -> list[FrameResult]:
    tracker = NoseTracker(cfg)
    return [result(k, d, tracker.update(d, k * DT)) for k, d in enumerate(detections)]


def test_track_counts_acquisition_replacement_and_loss():
    cfg = TrackerConfig(report_coast_s=2.5 * DT)
    tracker, stats = NoseTracker(cfg), TrackStats()
    assert stats.snapshot() == TrackSnapshot(status="none", confidence=0.0, detected_frames=0, tracked_frames=0,
                                             acquired=0, lost=0, tip_frames=0, tip_xyz_m=None)
    t = 0.0
    script = [hit(0.0)] * 6 + [hit(0.10)] * cfg.confirm_hits + [MISS] * 20 + [hit(-0.05)] * 4
    for d in script:  # confirmed at 0, replaced by a challenger at 10 cm, lost while missing, confirmed again
        stats.record(d, tracker.update(d, t))
        t += DT
    snap = stats.snapshot()
    assert snap.acquired == 3 and snap.lost == 1
    assert snap.detected_frames == 6 + cfg.confirm_hits + 4
    assert snap.status == "tracking" and 0.5 < snap.confidence < 1.0
    # 2 misses reported (report_coast_s), then the track coasts unreported until lost: one loss, not one per coast
    assert snap.tracked_frames == 6 + cfg.confirm_hits + 2 + 4  # new tracks are reported from their first hit


def test_a_loss_is_counted_when_a_new_track_starts_in_the_same_frame():
    cfg = TrackerConfig()
    tracker, stats = NoseTracker(cfg), TrackStats()
    misses = int(cfg.lost_after_s / DT)  # the track is still held after these
    script = [hit(0.0)] * 6 + [MISS] * misses + [hit(0.3)]  # the far hit arrives as the old track is dropped
    states = []
    for k, d in enumerate(script):
        states.append(tracker.update(d, k * DT))
        stats.record(d, states[-1])
    assert states[-2].status == "coasting" and states[-1].status == "tentative" and states[-1].reacquired
    assert stats.snapshot().lost == 1 and stats.snapshot().acquired == 1


def test_results_record_reports_the_track_beside_the_detection():
    rows = [result_record(r) for r in tracked_results([hit(0.01)] * 4 + [MISS])]
    assert [r["track"]["status"] for r in rows] == ["tentative", "tentative", "tracking", "tracking", "tracking"]
    assert rows[0]["track"]["nose_px"] is not None and rows[0]["track"]["reacquired"]  # a new track: reported
    untold = TrackerConfig(report_new=False)
    quiet = [result_record(r) for r in tracked_results([hit(0.01)] * 3, untold)]
    assert [r["track"]["nose_px"] is None for r in quiet] == [True, True, False]  # then only once confirmed
    last = rows[-1]
    assert last["accepted"] is False and last["nose_px"] is None  # the detection missed, the track coasts on
    assert not last["track"]["associated"] and last["track"]["confidence"] < rows[-2]["track"]["confidence"]
    u, v = INTRINSICS.project(np.array(last["track"]["nose_xyz_m"]))
    assert last["track"]["nose_px"] == pytest.approx([u, v], abs=0.01)
    assert u == pytest.approx(INTRINSICS.cx + INTRINSICS.fx * 0.01 / 0.5, abs=0.05)
    json.dumps(rows)  # JSON-ready
    assert result_record(result(0, hit(0.0), None))["track"] is None  # no detector model: no track


def test_batch_rows_leave_the_track_out():
    """A batch partition does not see the frames before it, so its rows carry the detection but not the track."""
    r = tracked_results([hit(0.01)] * 4)[-1]
    row = frame_row(r)
    assert "track" not in row and row["nose_xyz_m"] == result_record(r)["nose_xyz_m"]
    assert set(row) - {"track"} >= set(result_record(r)) - {"track", "timings_ms"}


def test_wire_format_carries_the_track():
    ring = SlotRing.create(2, INTRINSICS.shape, wire.PLANES)
    try:
        for i, r in enumerate(tracked_results([hit(0.0)] * 3 + [MISS] * 30)):
            back = wire.read(wire.write(r, i % 2, ring.views(i % 2)), ring, INTRINSICS)
            assert back.track == r.track and back.detection == r.detection
            assert np.array_equal(back.frame.range_m, r.frame.range_m, equal_nan=True)
            assert np.array_equal(back.mask, r.mask) and back.features.keys() <= r.features.keys()
    finally:
        ring.close()
    assert track_from(None) is None


def test_wire_format_carries_numbers_exactly_infinities_and_nan_included():
    """A frame without foreground scores inf; a residual can be NaN; times keep every bit."""
    ring = SlotRing.create(1, INTRINSICS.shape, wire.PLANES)
    try:
        r = result(7, Detection(None, None, math.inf, False), None)
        r.nfft_residual, r.arrival_s, r.timings_ms = math.nan, 12345.678901234567, {"fft": 0.1 + 0.2}
        back = wire.read(wire.write(r, 0, ring.views(0)), ring, INTRINSICS)
        assert back.detection.score == math.inf and math.isnan(back.nfft_residual)
        assert back.arrival_s == r.arrival_s and back.timings_ms == r.timings_ms and back.box == r.box
        assert back.frame.host_monotonic_s == r.frame.host_monotonic_s
    finally:
        ring.close()


def test_wire_format_carries_the_feature_maps_over_the_foreground_box_only():
    """Each viewed map arrives equal over the mask's bounding box; the slot outside it is not written (it keeps
    the previous frame's values, which the viewers never read)."""
    ring = SlotRing.create(1, INTRINSICS.shape, wire.PLANES)
    rng = np.random.default_rng(2)
    try:
        for i, (rows, cols) in enumerate(((slice(20, 90), slice(30, 120)), (slice(50, 60), slice(70, 75)))):
            r = result(i, MISS, None)
            r.mask[rows, cols] = rng.random((rows.stop - rows.start, cols.stop - cols.start)) < 0.7
            box = r.box = foreground_box(r.mask)
            for plane in r.features.values():
                plane[box] = rng.random(plane[box].shape)
            before = {name: view.copy() for name, view in ring.views(0).items()}
            back = wire.read(wire.write(r, 0, ring.views(0)), ring, INTRINSICS)
            assert back.box == box
            outside = np.ones(INTRINSICS.shape, bool)
            outside[box] = False
            for name, plane in back.features.items():
                assert np.array_equal(plane[box], r.features[name][box])
                assert np.array_equal(plane[outside], before[name][outside], equal_nan=True)
    finally:
        ring.close()


def test_viewer_logs_the_track_box_with_its_confidence(tmp_path):
    path = tmp_path / "track.rrd"
    target = RerunTarget(Config().rerun, "save", Config().intrinsics.shape, path=str(path))
    logger = RerunLogger(target.rec, INTRINSICS, point_cloud=False)
    results = tracked_results([hit(0.0)] * 5 + [MISS] * 20)
    for r in results:
        logger(r)
    logger.flush()
    target.close()
    tables = read_entities(str(path))
    boxes = tables[bp.TRACK_2D][1]
    counters = boxes.column("frame").to_pylist()
    assert counters == list(range(len(results)))  # a box while confirmed, a Clear once lost
    for row, r in enumerate(results):
        centers = boxes.column("Boxes2D:centers")[row].as_py()
        if r.track.reported:
            # Rerun's pixel origin is the top-left pixel's corner, tofd's its centre (viewer/pixels.py)
            assert centers == [pytest.approx([c + 0.5 for c in track_px(r.track, INTRINSICS)])]
            assert boxes.column("Boxes2D:labels")[row].as_py() == [f"track {r.track.confidence:.2f}"]
        else:
            assert not centers
    assert results[2].track.reported and not results[-1].track.reported
    confidence = tables[bp.TRACK_CONFIDENCE][1]
    assert confidence.column("Scalars:scalars").to_pylist() == [[r.track.confidence] for r in results]
    detected = tables[bp.NOSE_2D][1].column("frame").to_pylist()
    assert detected == counters  # the detection stays its own entity beside the track


def test_metrics_report_the_track_of_a_live_run(tmp_path):
    cfg = load_config(write_config(tmp_path))
    model = load_service_model(cfg)
    snapshot = []
    metrics = ServiceMetrics(lambda: snapshot[0]())
    pipeline = Pipeline(cfg, "latest", writers=(metrics.observe,), model=model)
    snapshot.append(pipeline.snapshot)
    server = HealthServer("127.0.0.1", 0, pipeline.snapshot, lambda: pipeline.running, stale_after_s=5.0,
                          metrics=metrics).start()
    try:
        pipeline.start(RenderedSource(300, fps=30, n_distinct=1))  # a face holding still: one track, never lost
        deadline = time.monotonic() + 60
        while pipeline.ledger.frames_out < 10 and time.monotonic() < deadline:
            time.sleep(0.05)
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/metrics", timeout=5) as resp:
            text = resp.read().decode()
    finally:
        pipeline.close()
        server.close()
    assert metric_values(text, "tofd_track_status") == {'{status="none"}': 0.0, '{status="tentative"}': 0.0,
                                                        '{status="coasting"}': 0.0, '{status="tracking"}': 1.0}
    assert metric_values(text, "tofd_track_acquired_total")[""] == 1
    assert metric_values(text, "tofd_track_lost_total")[""] == 0
    detected = metric_values(text, "tofd_nose_detected_frames_total")[""]
    assert detected >= 10 and metric_values(text, "tofd_nose_tracked_frames_total")[""] == detected
    assert metric_values(text, "tofd_track_confidence")[""] > 0.9
    tips = metric_values(text, "tofd_nose_tip_frames_total")[""]
    assert 0.8 * detected <= tips <= detected  # the accepted pixel refined to a sub-pixel tip in most frames
    assert 0.3 < metric_values(text, "tofd_nose_tip_meters")['{axis="z"}'] < 0.8
    assert "# TYPE tofd_track_lost_total counter" in text


def test_metrics_without_a_model_have_no_track():
    cfg = Config()
    pipeline = Pipeline(cfg, "lossless")
    try:
        text = ServiceMetrics(pipeline.snapshot).render().decode()
    finally:
        pipeline.close()
    assert "tofd_track" not in text and pipeline.snapshot().track is None
