"""The pipeline on rendered frames: ledger and queue policies, shared-memory workers, ordering, worker death."""

import os
import signal
import threading
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.tracking import NoseTracker
from tofd.config import Config, load_config
from tofd.service.model import load_detector
from tofd.service.pipeline import DropLedger, Pipeline
from tofd.service.pipeline.queues import StageQueue
from tofd.service.pipeline.stages import pipeline_families
from tofd_testing.chaos_helpers import wait_for
from tofd_testing.pipeline_sources import RenderedSource, dropped_frames, write_config

CFG = Config()


def test_ledger_counts_every_frame_once():
    ledger = DropLedger()
    for seq in range(5):
        ledger.admit(seq, 100 + seq)
    ledger.deliver(0)
    ledger.drop(1, "features", "worker_died")
    ledger.advance(2, "sink")
    assert ledger.consistent() and ledger.pending == 3
    with pytest.raises(RuntimeError, match="not in flight"):
        ledger.deliver(1)
    with pytest.raises(ValueError, match="stage"):
        ledger.drop(3, "nowhere", "x")
    assert ledger.drop_pending("shutdown") == 3
    ledger.close()
    ledger.deliver(2)  # a late report after shutdown is ignored, not double counted
    s = ledger.summary()
    assert (s["frames_in"], s["frames_out"], s["frames_dropped"], s["consistent"]) == (5, 1, 4, True)
    assert {(d["frame_counter"], d["stage"], d["reason"]) for d in dropped_frames(s)} == {
        (101, "features", "worker_died"), (102, "sink", "shutdown"), (103, "capture", "shutdown"),
        (104, "capture", "shutdown")}


def test_latest_queue_drops_oldest_and_lossless_blocks():
    never = threading.Event()
    latest = StageQueue("latest", 2)
    assert latest.put(1, never) == [] and latest.put(2, never) == []
    assert latest.put(3, never) == [1]
    assert [latest.get(0), latest.get(0), latest.get(0)] == [2, 3, None]

    lossless, abort = StageQueue("lossless", 1), threading.Event()
    lossless.put("a", abort)
    got = []
    consumer = threading.Timer(0.2, lambda: got.append(lossless.get(1)))
    consumer.start()
    t0 = time.monotonic()
    assert lossless.put("b", abort) == []  # blocked until the consumer took "a"
    assert time.monotonic() - t0 >= 0.15 and got == ["a"]
    abort.set()
    assert lossless.put("c", abort) == ["c"]  # full and aborting: handed back, never lost silently


def test_dispatch_waits_for_a_free_slot_not_just_a_free_worker():
    """A worker counts as free as soon as its result arrives, but the result holds its slot until it is read:
    wait_free must wait for the slot too, or the dispatcher spins on a submit that fails."""
    from tofd.service.pipeline.pool import WorkerPool

    pool = WorkerPool({}, 1, 1, (4, 4), cap=1, timeout_s=1.0, max_failures=1)  # workers are not started
    try:
        pool.workers[0].ready = True
        never = threading.Event()
        assert pool.wait_free(0.0, never)
        slot = pool.ring.acquire()  # a result being read holds the only slot
        assert not pool.wait_free(0.05, never)
        assert not pool.submit(0, np.zeros((4, 4), np.float32), np.zeros((4, 4), np.float32))
        threading.Timer(0.1, pool.release, (slot,)).start()
        assert pool.wait_free(5.0, never)  # woken by release
    finally:
        pool.close()


class Collect:
    """A sink that keeps what it is given."""

    def __init__(self, delay_s: float = 0.0):
        self.results, self.delay_s = [], delay_s

    def __call__(self, r):
        time.sleep(self.delay_s)
        self.results.append(r)


def run_pipeline(source, policy, cfg=CFG, sink=None, during=None, timeout=60):
    sink = sink or Collect()
    pipeline = Pipeline(cfg, policy, writers=(sink,))
    pipeline.start(source)
    if during is not None:
        during(pipeline, sink)
    assert pipeline.wait(timeout)
    return pipeline, pipeline.close(), sink


def test_lossless_delivers_every_frame_in_order_with_the_in_process_features():
    source = RenderedSource(24, skip_counters=(10,), n_distinct=3)
    pipeline, summary, sink = run_pipeline(source, "lossless")
    counters = [r.frame.frame_counter for r in sink.results]
    assert counters == source.emitted == [c for c in range(24) if c != 10]
    assert summary["consistent"] and summary["frames_out"] == 23 and summary["frames_dropped"] == 0
    assert summary["gaps"] == [{"after_counter": 9, "next_counter": 11, "kind": "counter_gap"}]
    assert sink.results[10].gap_before == "counter_gap"

    reference = FeatureExtractor(CFG.intrinsics, CFG.features, CFG.segmentation, pipeline_families(CFG, False))
    for r in sink.results[:3]:  # shared-memory worker result == direct computation, bit for bit
        ref = reference(r.frame.range_m, r.frame.amplitude)
        np.testing.assert_array_equal(r.mask, ref.mask)
        assert set(r.features) == set(ref.maps)  # the computed maps, no placeholders for the others
        for name, ref_map in ref.maps.items():
            np.testing.assert_array_equal(r.features[name], ref_map, err_msg=name)
        assert r.mask.sum() > 300  # a face, not an empty frame
        rows, cols = r.box  # the foreground's bounding box, which the maps are NaN outside
        assert r.mask[rows, cols].sum() == r.mask.sum()
        assert r.mask[rows.start].any() and r.mask[rows.stop - 1].any()
        assert r.mask[:, cols.start].any() and r.mask[:, cols.stop - 1].any()
        assert np.isnan(np.delete(r.features["range_nfft_eps0"], np.s_[rows], axis=0)).all()
    assert {"capture", "queue", "segmentation", "fft", "nfft", "latency"} <= set(sink.results[0].timings_ms)
    assert not pipeline.running


class FailingWriter:
    """A results writer whose write of one frame counter fails with an error that is not an I/O error (an OSError
    fails the whole output instead: tests/commands/test_full_disk.py)."""

    def __init__(self, bad_counter: int):
        self.bad_counter, self.written = bad_counter, []

    def __call__(self, result) -> None:
        if result.frame.frame_counter == self.bad_counter:
            raise ValueError("cannot encode this frame")
        self.written.append(result.frame.frame_counter)


def test_a_failing_writer_is_ledgered_as_the_sink_stage_naming_the_writer():
    writer = FailingWriter(2)
    _, summary, _ = run_pipeline(RenderedSource(5, n_distinct=2), "lossless", sink=writer)
    assert writer.written == [0, 1, 3, 4]
    assert summary["consistent"] and summary["frames_out"] == 4 and summary["dropped_by_stage"] == {"sink": 1}
    (drop,) = dropped_frames(summary)
    assert drop["frame_counter"] == 2 and drop["stage"] == "sink"
    assert str(drop["reason"]).startswith("writer_error: ValueError")
    assert summary["viewer_dropped"] == 0  # the viewer is not what failed


@pytest.mark.parametrize("kept", [(), ("range_nfft_eps0", "amp_nfft_eps0")])
def test_results_carry_only_the_maps_asked_for(kept):
    """result_maps: the maps results carry, of those computed (amp_nfft_eps0 is not computed here); the mask and
    the rest of each result are as with every map."""
    sink = Collect()
    pipeline = Pipeline(CFG, "lossless", writers=(sink,), result_maps=kept)
    pipeline.start(RenderedSource(4, n_distinct=2))
    assert pipeline.wait(60)
    pipeline.close()
    reference = FeatureExtractor(CFG.intrinsics, CFG.features, CFG.segmentation, pipeline_families(CFG, False))
    assert len(sink.results) == 4
    for r in sink.results:
        ref = reference(r.frame.range_m, r.frame.amplitude)
        np.testing.assert_array_equal(r.mask, ref.mask)
        assert set(r.features) == set(kept) & set(ref.maps)
        for name, computed in r.features.items():
            np.testing.assert_array_equal(computed, ref.maps[name], err_msg=name)


def test_killed_worker_is_ledgered_restarted_and_the_run_finishes():
    source = RenderedSource(40, n_distinct=3)
    killed = []

    def kill_one(pipeline, sink):
        deadline = time.monotonic() + 30
        while len(sink.results) < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
        victim = pipeline.workers[0]
        while not victim.inflight and time.monotonic() < deadline:  # make sure it holds a frame
            time.sleep(0.001)
        killed.append(victim.pid)
        os.kill(victim.pid, signal.SIGKILL)

    pipeline, summary, sink = run_pipeline(source, "lossless", during=kill_one)
    lost = [d for d in dropped_frames(summary) if d["reason"] == "worker_died"]
    assert len(lost) >= 1 and all(d["stage"] == "features" for d in lost)
    assert summary["frames_dropped"] == len(lost)
    assert summary["consistent"] and summary["frames_in"] == 40
    assert pipeline.worker_restarts >= 1 and pipeline.workers[0].pid != killed[0]
    delivered = [r.frame.frame_counter for r in sink.results]
    assert delivered == sorted(delivered) and len(delivered) == 40 - len(lost)
    assert set(delivered).isdisjoint(d["frame_counter"] for d in lost)


class GatedSink(Collect):
    """A sink that blocks on every frame until `gate` is set (a stalled consumer)."""

    def __init__(self):
        super().__init__()
        self.gate, self.waiting = threading.Event(), threading.Event()

    def __call__(self, r):
        self.waiting.set()
        self.gate.wait(120)
        super().__call__(r)


@pytest.mark.slow
def test_live_policy_drops_instead_of_blocking_and_never_goes_back_in_time():
    cfg = replace(CFG, pipeline=replace(CFG.pipeline, sink_queue=2))
    source = RenderedSource(45, fps=60, n_distinct=3)
    sink = GatedSink()

    def while_the_sink_is_stalled(pipeline, sink):
        # the whole source is captured while the sink holds its first frame: capture is never held back
        assert wait_for(lambda: pipeline.ledger.frames_in == 45 and sink.waiting.is_set(), 60)
        assert sink.results == []
        sink.gate.set()

    _, summary, sink = run_pipeline(source, "latest", cfg=cfg, sink=sink, during=while_the_sink_is_stalled)
    assert summary["consistent"] and summary["frames_in"] == 45
    assert summary["frames_dropped"] > 0 and summary["frames_out"] == len(sink.results)
    assert {d["reason"] for d in dropped_frames(summary)} <= {"queue_full", "superseded", "late"}
    assert summary["frames_out"] <= 1 + cfg.pipeline.sink_queue + cfg.pipeline.workers + 1  # bounded backlog
    delivered = [r.frame.frame_counter for r in sink.results]
    assert delivered == sorted(set(delivered))


@pytest.mark.slow
def test_a_stopped_worker_does_not_hold_back_live_output():
    """SIGSTOP one worker: the other's frames keep coming out (latest-wins), the held frame is ledgered as
    late, memory stays within the slot ring; a lossless run would wait for it instead."""
    cfg = replace(CFG, pipeline=replace(CFG.pipeline, worker_timeout_s=120.0))
    source = RenderedSource(150, fps=30, n_distinct=3)
    stopped, backlog = [], []

    def stop_one(pipeline, sink):
        assert wait_for(lambda: len(sink.results) >= 5 and pipeline.workers[0].inflight, 60, poll_s=0.001)
        victim = pipeline.workers[0]
        os.kill(victim.pid, signal.SIGSTOP)
        stopped.append((victim.pid, set(victim.inflight), len(sink.results)))
        try:
            ok = wait_for(lambda: (backlog.append(pipeline.snapshot().queue_depth.get("reorder", 0)) or
                                   len(sink.results) >= stopped[0][2] + 30), 120, poll_s=0.05)
            assert ok, "live output stopped with the worker"
        finally:
            os.kill(victim.pid, signal.SIGCONT)

    pipeline, summary, sink = run_pipeline(source, "latest", cfg=cfg, during=stop_one)
    held = stopped[0][1]
    late = {d["seq"] for d in dropped_frames(summary) if d["reason"] == "late"}
    assert held and held <= late  # the frame the stopped worker held was dropped as late, not waited for
    assert summary["consistent"] and summary["frames_in"] == 150
    assert max(backlog) <= pipeline.pool.ring.n_slots  # finished frames never pile up behind the stopped one
    delivered = [r.seq for r in sink.results]
    assert delivered == sorted(set(delivered)) and late.isdisjoint(delivered)


def test_detection_in_the_workers_equals_the_detector_on_the_frame(tmp_path):
    cfg = load_config(write_config(tmp_path))
    detector = load_detector(cfg)
    sink = Collect()
    pipeline = Pipeline(cfg, "lossless", writers=(sink,), model=detector.model)
    pipeline.start(RenderedSource(6, n_distinct=3))
    assert pipeline.wait(60)
    pipeline.close()
    assert len(sink.results) == 6
    for r in sink.results:
        assert r.detection == detector.detect_frame(r.frame.range_m, r.frame.amplitude)
        assert r.timings_ms["detection"] > 0
    assert any(r.detection.accepted for r in sink.results)
    tracker = NoseTracker()  # the pipeline tracks the detections in frame order
    for r in sink.results:
        assert r.track == tracker.update(r.detection, r.frame.timestamp_us / 1e6)


def test_the_supervisor_returns_when_the_pipeline_ends_not_at_its_next_tick(monkeypatch):
    """supervise() waits on the pipeline itself: a run's time (hence the fps in its summary) ends when the last frame
    is through, not at the supervisor's next quarter-second tick, which would round a short replay's time up."""
    from tofd.service import supervise as supervise_module
    from tofd.service.signals import StopSignals

    def no_sleep(seconds: float) -> None:
        raise AssertionError(f"the supervisor slept {seconds} s instead of waiting on the pipeline")

    pipeline = Pipeline(CFG, "lossless", writers=(Collect(),))
    pipeline.start(RenderedSource(3, n_distinct=2))
    monkeypatch.setattr(supervise_module, "time", SimpleNamespace(monotonic=time.monotonic, sleep=no_sleep))
    assert pipeline.running
    with StopSignals() as stop:
        supervise_module.supervise(pipeline, stop, None)
    assert not pipeline.running  # it returned because the pipeline ended
    assert pipeline.close()["frames_out"] == 3
