"""The threaded pipeline: capture thread -> worker processes (features, detection) -> sink thread.

Threads in the parent process:
- capture: iterates the FrameSource, admits each frame to the ledger, marks device gaps, queues it;
- dispatch: copies a queued frame into a free shared-memory slot and hands the slot to a worker;
- collect: receives worker results (or notices a dead worker: its frames are ledgered, it is restarted),
  copies the maps out of the slot, orders the frames and queues them for the sink;
- sink: logs to Rerun (optional) and writes results (optional); a frame is delivered when this is done.

Queue policy (see queues.py): "latest" for live sources (the dispatch queue holds only the newest frame
and each worker holds at most one, the sink queue drops its oldest), "lossless" for replay (every queue
blocks). Either way the collector hands frames to the sink in sequence order. Every drop goes to the
DropLedger with its stage and reason.

Timings per frame (ms): capture (driver receive -> admitted), queue (admitted -> sent to a worker),
segmentation, fft, nfft, detection (in the worker), logging (Rerun), latency (driver receive -> sink done).
Workers run the detector too (it is ~4 ms of numpy per frame: in the parent it would compete for the GIL).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import wait as wait_ready

from drivers.frame import Frame
from drivers.intrinsics import Intrinsics
from drivers.source import FrameSource
from tofd.algorithm.detector import NoseModel
from tofd.algorithm.names import MAP_NAMES
from tofd.algorithm.tracking import NoseTracker
from tofd.config import Config
from tofd.service.pipeline.ledger import DropLedger
from tofd.service.pipeline.queues import Policy, StageQueue
from tofd.service.pipeline.results import FrameResult
from tofd.service.pipeline.slots import SlotRing
from tofd.service.pipeline.stages import detection_from
from tofd.service.pipeline.stats import PipelineStats
from tofd.service.pipeline.worker import WorkerHandle

log = logging.getLogger(__name__)

Sink = Callable[[FrameResult], None]
POLL_S = 0.1  # seconds: how often idle threads re-check the stop/abort flags


class PipelineError(RuntimeError):
    """The pipeline cannot go on (workers that cannot start or keep dying, a failing source)."""


@dataclasses.dataclass(slots=True)
class _Queued:
    seq: int
    frame: Frame
    origin_s: float  # monotonic: driver receive time (or arrival at the capture thread)
    admitted_s: float  # monotonic: entered the pipeline
    sent_s: float = 0.0  # monotonic: handed to a worker
    gap_before: str = ""  # device gap kind just before this frame ("" = none)


class Pipeline:
    """Run frames from a FrameSource through the stages; see the module docstring.

    `viewer` is called for every frame on the sink thread (its time is the "logging" stage), then each of
    `writers`. `model`: the workers run the nose detector of cfg.detector with this model (None: no detection).
    `live_source`: the frames' host receive times are this process's monotonic clock (a camera), so latency
    counts from there; else (replay) from the capture thread's arrival. Use: start(source), then wait() or stop().
    """

    def __init__(self, cfg: Config, policy: Policy, intrinsics: Intrinsics | None = None,
                 viewer: Sink | None = None, writers: tuple[Sink, ...] = (), model: NoseModel | None = None,
                 live_source: bool = True):
        pc = cfg.pipeline
        self.cfg, self.policy, self.intrinsics = cfg, policy, intrinsics or cfg.intrinsics
        self.viewer, self.writers, self.live_source = viewer, writers, live_source
        self.ledger = DropLedger()
        self.stats = PipelineStats(pc.stats_window)
        self.ring = SlotRing.create(pc.workers * pc.tasks_per_worker, self.intrinsics.shape)
        spec = json.dumps({"shm": self.ring.name, "n_slots": self.ring.n_slots, "shape": self.ring.shape,
                           "config": _config_table(cfg), "intrinsics": self.intrinsics.to_dict(),
                           "model": None if model is None else model.to_dict()})
        self.workers = [WorkerHandle(i, spec) for i in range(pc.workers)]
        self.inq: StageQueue[_Queued] = StageQueue(policy, 1 if policy == "latest" else pc.input_queue)
        self.outq: StageQueue[FrameResult] = StageQueue(policy, pc.sink_queue)
        self.source: FrameSource | None = None
        self.error: str | None = None
        self.worker_restarts = 0
        self._lock = threading.Condition()  # guards workers' pipes/inflight and the slot ring's bookkeeping
        self._queued: dict[int, _Queued] = {}
        self._gone: set[int] = set()  # lossless ordering: dropped seqs the collector must skip
        self._done: dict[int, FrameResult] = {}
        self._next_emit = 0
        self.tracker = None if model is None else NoseTracker()  # updated in sequence order (_emit_ordered)
        self._failures = 0
        self._capture_done = threading.Event()
        self._dispatch_done = threading.Event()
        self._collect_done = threading.Event()
        self._abort = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closed = False
        self._max_frames: int | None = None

    # ---------------------------------------------------------------- lifecycle
    def start(self, source: FrameSource, max_frames: int | None = None) -> None:
        """Start the workers (waiting until they are ready), then the threads; capture stops after
        `max_frames` frames (None = until the source ends or stop())."""
        self.source, self._max_frames = source, max_frames
        for w in self.workers:
            w.start()
        self._spawn("collect", self._collect_loop)
        deadline = time.monotonic() + self.cfg.pipeline.worker_start_timeout_s
        with self._lock:
            ok = self._lock.wait_for(lambda: all(w.ready for w in self.workers) or self.error is not None,
                                     max(0.0, deadline - time.monotonic()))
        if not ok or self.error is not None:
            self._abort.set()
            self.close()
            raise PipelineError(self.error or "feature workers did not become ready in "
                                f"{self.cfg.pipeline.worker_start_timeout_s:g} s")
        self._spawn("dispatch", self._dispatch_loop)
        self._spawn("sink", self._sink_loop)
        self._spawn("capture", self._capture_loop)

    def stop(self) -> None:
        """Stop capturing (the source is closed); frames already in the pipeline are drained by wait()."""
        if self.source is not None:
            self.source.close()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the pipeline to finish (end of source or stop()); True if it finished in time."""
        deadline = None if timeout is None else time.monotonic() + timeout
        for t in self._threads:
            t.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        return not any(t.is_alive() for t in self._threads)

    @property
    def running(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def close(self) -> dict:
        """Drain (up to drain_timeout_s), then stop the workers and release shared memory; the ledger summary.

        Frames still in flight after the drain timeout are ledgered as dropped ("shutdown").
        """
        if self._closed:
            return self.ledger.summary()
        self._closed = True
        self.stop()
        if not self.wait(self.cfg.pipeline.drain_timeout_s):
            log.warning("pipeline did not drain in %.1f s; dropping what is left", self.cfg.pipeline.drain_timeout_s)
        self._abort.set()
        self.wait(2.0)
        for w in self.workers:
            w.stop(2.0)
        self.ledger.drop_pending("shutdown")
        self.ledger.close()
        self.ring.close()
        return self.ledger.summary()

    def __enter__(self) -> Pipeline:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spawn(self, name: str, target: Callable[[], None]) -> None:
        def guarded() -> None:
            try:
                target()
            except Exception as exc:  # a crashed thread must stop the service, not hang it
                log.exception("pipeline thread %s failed", name)
                self._fail(f"{name} thread: {type(exc).__name__}: {exc}")

        t = threading.Thread(target=guarded, name=f"tofd-{name}", daemon=True)
        self._threads.append(t)
        t.start()

    def _fail(self, message: str) -> None:
        with self._lock:
            self.error = self.error or message
            self._lock.notify_all()
        self._abort.set()
        self.stop()

    def _drop(self, seq: int, stage: str, reason: str) -> None:
        self.ledger.drop(seq, stage, reason)
        with self._lock:
            self._queued.pop(seq, None)
            self._gone.add(seq)

    # ---------------------------------------------------------------- capture
    def _capture_loop(self) -> None:
        source, seq, last_counter = self.source, 0, None
        reconnects = source.counters["reconnect"]
        try:
            for frame in source:
                now = time.monotonic()
                if self._abort.is_set() or (self._max_frames is not None and seq >= self._max_frames):
                    break
                origin = min(frame.host_monotonic_s, now) if self.live_source else now
                gap = ""
                if source.counters["reconnect"] != reconnects:
                    reconnects, gap = source.counters["reconnect"], "reconnect"
                elif last_counter is not None and frame.frame_counter != last_counter + 1:
                    gap = "counter_gap"
                if gap:
                    self.ledger.mark_gap(-1 if last_counter is None else last_counter, frame.frame_counter, gap)
                last_counter = frame.frame_counter
                self.ledger.admit(seq, frame.frame_counter)
                item = _Queued(seq, frame, origin, time.monotonic(), gap_before=gap)
                with self._lock:
                    self._queued[seq] = item
                for old in self.inq.put(item, self._abort):
                    stage, reason = ("features", "superseded") if old is not item else ("capture", "shutdown")
                    self._drop(old.seq, stage, reason)
                seq += 1
        except Exception as exc:
            self._fail(f"source: {type(exc).__name__}: {exc}")
        finally:
            self._capture_done.set()

    # ---------------------------------------------------------------- dispatch
    def _free_worker(self) -> WorkerHandle | None:
        cap = 1 if self.policy == "latest" else self.cfg.pipeline.tasks_per_worker  # live: no frame waits in a pipe
        ready = [w for w in self.workers if w.ready and len(w.inflight) < cap]
        return min(ready, key=lambda w: len(w.inflight)) if ready else None

    def _dispatch_loop(self) -> None:
        item: _Queued | None = None  # taken from the queue, waiting for a worker
        try:
            while not self._abort.is_set():
                with self._lock:
                    if not self._lock.wait_for(lambda: self._free_worker() is not None or self._abort.is_set(),
                                               POLL_S):
                        continue
                if item is not None and self.policy == "latest" and len(self.inq):
                    self._drop(item.seq, "features", "superseded")
                    item = None
                if item is None:
                    item = self.inq.get(POLL_S)
                if item is None:
                    if self._capture_done.is_set() and len(self.inq) == 0:
                        break
                    continue
                if self._dispatch(item):
                    item = None
        finally:
            self._dispatch_done.set()

    def _dispatch(self, item: _Queued) -> bool:
        """Copy the frame into a free slot and send it to the least busy worker; False if none is free."""
        with self._lock:
            worker = self._free_worker()
            slot = self.ring.acquire(0) if worker is not None else None
            if slot is None:  # a worker died between the wait and now
                return False
            views = self.ring.views(slot)
            views["range_m"][...] = item.frame.range_m
            views["amplitude"][...] = item.frame.amplitude
            self.ledger.advance(item.seq, "features")
            item.sent_s = time.monotonic()
            try:
                worker.send(item.seq, slot)
                return True
            except OSError:  # it died just now; the collector restarts it
                self.ring.release(slot)
                return False

    # ---------------------------------------------------------------- collect
    def _collect_loop(self) -> None:
        try:
            while not self._abort.is_set():
                with self._lock:
                    conns = {w.results: w for w in self.workers if w.process is not None}
                    sentinels = {w.sentinel: w for w in self.workers if w.process is not None}
                for obj in wait_ready([*conns, *sentinels], POLL_S):
                    if obj in conns:
                        self._receive(conns[obj])
                for obj in wait_ready(list(sentinels), 0):
                    self._worker_died(sentinels[obj], "worker_died")
                self._check_timeouts()
                self._emit_ordered()
                if self._dispatch_done.is_set() and not any(w.inflight for w in self.workers) and not self._done:
                    break
        finally:
            self._collect_done.set()

    def _receive(self, worker: WorkerHandle) -> None:
        try:
            msg = worker.receive()
        except (EOFError, OSError):
            return  # the sentinel reports the death
        if "ready" in msg:
            with self._lock:
                worker.ready = True
                self._lock.notify_all()
            return
        self._handle_result(worker, msg)

    def _handle_result(self, worker: WorkerHandle, msg: dict) -> None:
        seq, slot = msg["seq"], msg["slot"]
        with self._lock:
            worker.inflight.pop(seq)
            item = self._queued.pop(seq)
            if "error" in msg:
                self.ring.release(slot)
                self._lock.notify_all()
        if "error" in msg:
            self.ledger.drop(seq, "features", f"error: {msg['error']}")
            with self._lock:
                self._gone.add(seq)
            return
        views = self.ring.views(slot)
        result = FrameResult(
            seq=seq, frame=item.frame, mask=views["mask"].copy(),
            features={name: views[name].copy() for name in MAP_NAMES},
            nfft_iterations=msg["nfft_iterations"], nfft_residual=msg["nfft_residual"], arrival_s=item.origin_s,
            gap_before=item.gap_before, detection=detection_from(msg),
            timings_ms={"capture": (item.admitted_s - item.origin_s) * 1e3,
                        "queue": (item.sent_s - item.admitted_s) * 1e3, **msg["timings_ms"]})
        with self._lock:
            self.ring.release(slot)
            self._failures = 0
            self._lock.notify_all()
        self._done[seq] = result

    def _worker_died(self, worker: WorkerHandle, reason: str) -> None:
        """Ledger the frames a dead worker held, then restart it (unless shutting down or failing)."""
        with self._lock:
            worker.ready = False  # the dispatcher must not pick it any more
        while worker.results.poll(0):  # results it sent before dying are still good
            try:
                msg = worker.receive()
            except (EOFError, OSError):
                break
            if "seq" in msg:
                self._handle_result(worker, msg)
        worker.process.join(1.0)
        with self._lock:
            lost = dict(worker.inflight)
            worker.inflight.clear()
            for seq, (slot, _) in lost.items():
                self.ring.release(slot)
                self._queued.pop(seq, None)
                self._gone.add(seq)
            self._lock.notify_all()
        for seq in sorted(lost):
            self.ledger.drop(seq, "features", reason)
        log.warning("feature worker %d (pid %s) died; %d frame(s) lost", worker.index, worker.pid, len(lost))
        worker.stop(0.1)
        self._failures += 1
        if self._failures > self.cfg.pipeline.max_worker_failures:
            self._fail(f"feature workers died {self._failures} times in a row without processing a frame")
            return
        if self._capture_done.is_set() and self.policy == "latest":
            return  # live shutdown: nothing left for it to do
        with self._lock:
            worker.start()
            self.worker_restarts += 1

    def _check_timeouts(self) -> None:
        limit = self.cfg.pipeline.worker_timeout_s
        for w in self.workers:
            if w.process is not None and w.inflight and w.oldest_task_age_s() > limit:
                log.warning("feature worker %d held a frame for more than %.1f s; killing it", w.index, limit)
                w.kill()
                self._worker_died(w, "worker_timeout")

    def _emit_ordered(self) -> None:
        """Queue finished frames for the sink in sequence order (a frame never follows a newer one),
        skipping the sequence numbers that were dropped."""
        while True:
            with self._lock:
                gone = self._next_emit in self._gone
                if gone:
                    self._gone.discard(self._next_emit)
            if gone:
                self._next_emit += 1
            elif self._next_emit in self._done:
                result = self._done.pop(self._next_emit)
                if self.tracker is not None:
                    result.track = self.tracker.update(result.detection, result.frame.timestamp_us / 1e6)
                self._to_sink(result)
                self._next_emit += 1
            else:
                return

    def _to_sink(self, result: FrameResult) -> None:
        self.ledger.advance(result.seq, "viewer")
        for old in self.outq.put(result, self._abort):
            self._drop(old.seq, "viewer", "queue_full" if old is not result else "shutdown")

    # ---------------------------------------------------------------- sink
    def _sink_loop(self) -> None:
        while True:
            result = self.outq.get(POLL_S)
            if result is None:
                if self._abort.is_set() or (self._collect_done.is_set() and len(self.outq) == 0):
                    return
                continue
            try:
                if self.viewer is not None:
                    t0 = time.perf_counter()
                    self.viewer(result)
                    result.timings_ms["logging"] = (time.perf_counter() - t0) * 1e3
                result.timings_ms["latency"] = (time.monotonic() - result.arrival_s) * 1e3
                for write in self.writers:
                    write(result)
            except Exception as exc:
                log.exception("sink failed on frame %d", result.frame.frame_counter)
                self._drop(result.seq, "viewer", f"error: {type(exc).__name__}: {exc}")
                continue
            self.ledger.deliver(result.seq)
            self.stats.record(result.timings_ms)

    # ---------------------------------------------------------------- monitoring
    def snapshot(self) -> dict:
        """Counters, rates, timings and queue depths for /metrics and the run summary."""
        with self._lock:
            inflight = sum(len(w.inflight) for w in self.workers)
            alive = sum(w.alive() for w in self.workers)
        counters = dict(self.source.counters) if self.source is not None else {}
        return {
            "frames_in": self.ledger.frames_in,
            "frames_out": self.ledger.frames_out,
            "frames_dropped": self.ledger.frames_dropped,
            "drops": self.ledger.drops_by(),
            "gaps": len(self.ledger.gaps),
            "fps": self.stats.fps(),
            "timings_ms": self.stats.quantiles_ms(),
            "queue_depth": {"dispatch": len(self.inq), "workers": inflight, "sink": len(self.outq)},
            "workers_alive": alive,
            "worker_restarts": self.worker_restarts,
            "device_events": counters,
            "last_delivery_age_s": self.stats.last_delivery_age_s(),
            "error": self.error,
        }


def _config_table(cfg: Config) -> dict:
    """The config as a TOML-like table (for the worker processes, which rebuild it with config_from_dict)."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))

