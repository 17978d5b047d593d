"""The pipeline: capture thread -> worker pool (features, detection) -> reorderer -> sink thread.

Threads in the parent process:
- capture: iterates the FrameSource, checks each frame (capture.py), admits it to the ledger, queues it;
- dispatch: hands a queued frame to the worker pool (pool.py: slots, workers, restarts, timeouts);
- collect: receives the workers' results, puts them in output order (reorder.py), queues them for the sink;
- sink: hands the frame to an inline viewer and the writers, then offers it to the best-effort viewer; a frame
  is delivered when written.

Queue policy (queues.py): "latest" for live sources (the dispatch queue holds only the newest frame, each
worker holds at most one, a finished frame never waits for an older one, the sink queue drops its
oldest), "lossless" for replay (every queue blocks, strict order). Every drop goes to the DropLedger with
its stage and reason. The viewer is best effort: an OfferingViewer (a ViewerProcess) never blocks the sink;
frames it refuses are ledgered as viewer drops. An InlineViewer (a RerunLogger in tests) is called on the sink
thread.

Timings per frame (ms): capture (driver receive -> admitted), queue (admitted -> sent to a worker),
segmentation, fft, nfft, detection (in the worker), logging (inline viewer only), latency (driver receive
-> written).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

from tofd.algorithm.detector import NoseModel
from tofd.algorithm.names import VIEWED_MAPS, family_maps
from tofd.algorithm.tracking import NoseTracker
from tofd.config import Config, config_table
from tofd.drivers.frame import COUNTER_LIMIT, Frame, frame_problem
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.source import FrameSource
from tofd.errors import TofdError
from tofd.service.pipeline import monitor
from tofd.service.pipeline.capture import GapTracker
from tofd.service.pipeline.ledger import DropLedger, LedgerSummary
from tofd.service.pipeline.messages import WorkerReply
from tofd.service.pipeline.monitor import PipelineSnapshot
from tofd.service.pipeline.pool import WorkerPool
from tofd.service.pipeline.queues import Policy, StageQueue
from tofd.service.pipeline.reorder import Reorderer
from tofd.service.pipeline.results import FrameResult
from tofd.service.pipeline.stages import frame_result, pipeline_families
from tofd.service.pipeline.stats import PipelineStats, TrackStats

log = logging.getLogger(__name__)

Sink = Callable[[FrameResult], None]
POLL_S = 0.1  # seconds: how often idle threads re-check the stop/abort flags
STOP_TIMEOUT_S = 2.0  # seconds close() gives the threads and workers to stop, by default


class PipelineError(TofdError, RuntimeError):
    """The pipeline cannot go on (workers that cannot start or keep dying, a failing source)."""


class OfferingViewer(Protocol):
    """A best-effort viewer: `offer` returns at once (or within `block_s`, sooner once `cancelled()` is true), False
    if it refused the frame, which is ledgered as a viewer drop for `drop_reason`. One whose output can fail also
    has `failure()`: (output file, why) once, when it failed (a full disk), else None."""

    drop_reason: str

    def offer(self, result: FrameResult, block_s: float, cancelled: Callable[[], bool]) -> bool: ...


class InlineViewer(Protocol):
    """A viewer called on the sink thread with each delivered frame; `flush` sends what it batches at the end."""

    def __call__(self, result: FrameResult) -> None: ...

    def flush(self) -> None: ...


@dataclasses.dataclass(slots=True)
class _Queued:
    seq: int
    frame: Frame
    origin_s: float  # monotonic: driver receive time (or arrival at the capture thread)
    admitted_s: float  # monotonic: entered the pipeline
    sent_s: float = 0.0  # monotonic: handed to a worker
    gap_before: str = ""  # device gap kind just before this frame ("" = none)


def maps_read(viewer: bool, writers_read_maps: bool = False) -> tuple[str, ...] | None:
    """Pipeline's `result_maps` given who reads the results: every computed map (None) when writers read maps, the
    viewed ones for a viewer, else none."""
    return None if writers_read_maps else VIEWED_MAPS if viewer else ()


class Pipeline:
    """Run frames from a FrameSource through the stages; see the module docstring.

    `viewer`: a best-effort OfferingViewer, offered each frame after it was delivered (the daemon's viewer
    process); `inline_viewer`: one called on the sink thread before `writers` (its time is the "logging" stage).
    `live_viewers`: more OfferingViewers (Foxglove), offered every delivered frame without waiting.
    `model`: the workers run the nose detector of cfg.detector with this model (None: no detection).
    `live_source`: the frames' host receive times are this process's monotonic clock (a camera), so latency
    counts from there; else (replay) from the capture thread's arrival.
    `result_maps`: the feature maps results carry, of those the workers compute (None: all of them); copying maps
    out of shared memory is a large part of this process's work, so runs whose sinks read none pass ().
    Use: start(source), then wait() or stop().
    """

    def __init__(self, cfg: Config, policy: Policy, intrinsics: Intrinsics | None = None,
                 viewer: OfferingViewer | None = None, inline_viewer: InlineViewer | None = None,
                 writers: tuple[Sink, ...] = (),
                 model: NoseModel | None = None, live_source: bool = True,
                 result_maps: tuple[str, ...] | None = None, live_viewers: tuple[OfferingViewer, ...] = ()):
        pc = cfg.pipeline
        self.cfg, self.policy, self.intrinsics = cfg, policy, intrinsics or cfg.intrinsics
        self.viewer, self.inline_viewer, self.writers, self.live_source = viewer, inline_viewer, writers, live_source
        self.live_viewers = live_viewers
        self.ledger = DropLedger()
        self.stats = PipelineStats(pc.stats_window)
        spec = {"config": config_table(cfg), "intrinsics": self.intrinsics.to_dict(),
                "model": None if model is None else model.to_dict()}
        self.pool = WorkerPool(spec, pc.workers, pc.tasks_per_worker, self.intrinsics.shape,
                               cap=1 if policy == "latest" else pc.tasks_per_worker, timeout_s=pc.worker_timeout_s,
                               max_failures=pc.max_worker_failures)
        self.workers = self.pool.workers
        self.order: Reorderer[FrameResult] = Reorderer(policy)
        computed = family_maps(pipeline_families(cfg, model is not None))
        self.maps = computed if result_maps is None else tuple(m for m in computed if m in result_maps)
        self.tracker = None if model is None else NoseTracker()  # updated in frame order (_to_sink)
        self.track_stats = None if model is None else TrackStats()
        self.inq: StageQueue[_Queued] = StageQueue(policy, 1 if policy == "latest" else pc.input_queue)
        self.outq: StageQueue[FrameResult] = StageQueue(policy, pc.sink_queue)
        self.source: FrameSource | None = None
        self.error: str | None = None
        self.outputs_failed: dict[str, str] = {}  # output file -> why it failed (it is written no more)
        self._failed_writers: set[Sink] = set()
        self._sink_errors: set[str] = set()  # failures of the sink already logged
        self._items: dict[int, _Queued] = {}  # seq -> frame, from admission until it leaves the workers
        self._items_lock = threading.Lock()
        self._capture_done = threading.Event()
        self._dispatch_done = threading.Event()
        self._collect_done = threading.Event()
        self._abort = threading.Event()
        self._threads: list[threading.Thread] = []
        self._closed = False
        self.abandoned: list[str] = []  # set by close(): parts that did not stop in time
        self._max_frames: int | None = None

    @property
    def worker_restarts(self) -> int:
        return self.pool.restarts

    # ---------------------------------------------------------------- lifecycle
    def start(self, source: FrameSource, max_frames: int | None = None,
              cancelled: Callable[[], bool] = lambda: False) -> None:
        """Start the workers (waiting until they are ready), then the threads; capture stops after
        `max_frames` frames (None = until the source ends or stop()). When `cancelled()` turns true while
        the workers start (a stop signal), starting is given up: the pipeline ends with no frame taken."""
        self.source, self._max_frames = source, max_frames
        self.pool.start()
        self._spawn("collect", self._collect_loop)
        ok = self.pool.wait_ready(self.cfg.pipeline.worker_start_timeout_s,
                                  lambda: self.error is not None or cancelled())
        if self.error is None and cancelled():
            self._abort.set()
            return
        if not ok or self.error is not None:
            self._abort.set()
            self.close()
            raise PipelineError(self.error or "feature workers did not become ready in "
                                f"{self.cfg.pipeline.worker_start_timeout_s:g} s")
        self._spawn("dispatch", self._dispatch_loop)
        self._spawn("sink", self._sink_loop)
        self._spawn("capture", lambda: self._capture_loop(source))

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

    def close(self, drain_timeout_s: float | None = None, stop_timeout_s: float = STOP_TIMEOUT_S) -> LedgerSummary:
        """Drain (up to `drain_timeout_s`, default pipeline.drain_timeout_s), then stop the threads and the
        workers within `stop_timeout_s` (killing workers that do not exit in time) and release shared memory;
        the ledger summary. Frames still in flight then are dropped ("shutdown"); what was left behind or
        killed is listed in `abandoned`."""
        if self._closed:
            return self.ledger.summary()
        self._closed = True
        self.stop()
        drain = self.cfg.pipeline.drain_timeout_s if drain_timeout_s is None else drain_timeout_s
        if not self.wait(drain):
            log.warning("pipeline did not drain in %.1f s; dropping what is left", drain)
            self.abandoned.append(f"drain: after {drain:.1f} s, {self.ledger.pending} frame(s) pending, "
                                  f"{self.pool.inflight} held by workers")
        self._abort.set()
        deadline = time.monotonic() + stop_timeout_s
        if not self.wait(stop_timeout_s / 2):
            self.abandoned.extend(f"thread {t.name}" for t in self._threads if t.is_alive())
        killed = self.pool.stop(max(0.0, deadline - time.monotonic()))
        self.abandoned.extend(f"worker {i} (killed)" for i in killed)
        self.ledger.drop_pending("shutdown")
        self.ledger.close()
        self.pool.close()
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
        self.error = self.error or message
        with self.pool.lock:
            self.pool.lock.notify_all()
        self._abort.set()
        self.stop()

    def _drop(self, seq: int, stage: str, reason: str) -> None:
        """Ledger a frame as dropped, once (a frame already dropped or delivered is ignored)."""
        with self._items_lock:
            if self._items.pop(seq, None) is None:
                return
        self.order.gone(seq)
        self.ledger.drop(seq, stage, reason)

    # ---------------------------------------------------------------- capture
    def _capture_loop(self, source: FrameSource) -> None:
        seq = 0
        gaps = GapTracker(source)
        try:
            for frame in source:
                seq = self._ledger_rejected(source, seq, gaps)
                now = time.monotonic()
                if self._abort.is_set() or (self._max_frames is not None and seq >= self._max_frames):
                    break
                self.ledger.admit(seq, _safe_counter(frame))
                problem = frame_problem(frame, self.pool.ring.shape)
                if problem is not None:
                    self.ledger.drop(seq, "capture", f"invalid_frame: {problem}")
                    self.order.gone(seq)
                    seq += 1
                    continue
                origin = min(frame.host_monotonic_s, now) if self.live_source else now
                previous = gaps.last_counter
                gap = gaps.gap_before(frame)
                if gap:
                    self.ledger.mark_gap(-1 if previous is None else previous, frame.frame_counter, gap)
                item = _Queued(seq, frame, origin, time.monotonic(), gap_before=gap)
                with self._items_lock:
                    self._items[seq] = item
                for old in self.inq.put(item, self._abort):
                    stage, reason = ("features", "superseded") if old is not item else ("capture", "shutdown")
                    self._drop(old.seq, stage, reason)
                seq += 1
            self._ledger_rejected(source, seq, gaps)
        except Exception as exc:
            self._fail(f"source: {type(exc).__name__}: {exc}")
        finally:
            self._capture_done.set()

    def _ledger_rejected(self, source: FrameSource, seq: int, gaps: GapTracker) -> int:
        """Admit and drop at capture the frames the source rejected; the next seq. A rejected frame with a valid
        counter was received, so it is no device gap."""
        for rejected in source.take_rejected():
            self.ledger.lost(seq, rejected.frame_counter, rejected.frames, rejected.reason)
            self.order.gone(seq)
            seq += 1
            counter = rejected.frame_counter + rejected.frames - 1
            if 0 <= counter < COUNTER_LIMIT and (gaps.last_counter is None or counter > gaps.last_counter):
                gaps.last_counter = counter
        return seq

    # ---------------------------------------------------------------- dispatch
    def _dispatch_loop(self) -> None:
        item: _Queued | None = None  # taken from the queue, waiting for a worker
        try:
            while not self._abort.is_set():
                if not self.pool.wait_free(POLL_S, self._abort):
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
                if self._submit(item):
                    item = None
        finally:
            self._dispatch_done.set()

    def _submit(self, item: _Queued) -> bool:
        self.ledger.advance(item.seq, "features")
        item.sent_s = time.monotonic()
        self.order.sent(item.seq)
        if self.pool.submit(item.seq, item.frame.range_m, item.frame.amplitude):
            return True
        self.order.unsent(item.seq)
        return False

    # ---------------------------------------------------------------- collect
    def _collect_loop(self) -> None:
        try:
            while not self._abort.is_set():
                restart = not (self._capture_done.is_set() and self.policy == "latest")
                self.pool.poll(POLL_S, self._on_result, self._on_lost, restart)
                if self.pool.error is not None:
                    self._fail(self.pool.error)
                    return
                ready, late = self.order.ready()
                for seq in late:
                    self._drop(seq, "features", "late")
                for result in ready:
                    self._to_sink(result)
                if self._dispatch_done.is_set() and not self.pool.inflight and not self.order.pending:
                    break
        finally:
            self._collect_done.set()

    def _on_result(self, seq: int, msg: WorkerReply) -> None:
        slot = msg["slot"]
        with self._items_lock:
            item = self._items.get(seq)
        if item is None:  # dropped meanwhile (live: late); the slot is all that is left to free
            self.pool.release(slot)
            return
        if "reply" not in msg:
            self.pool.release(slot)
            self._drop(seq, "features", f"error: {msg.get('error', 'no reply')}")
            return
        result = frame_result(seq, item.frame, self.pool.ring.views(slot), msg["reply"], self.maps,
                              arrival_s=item.origin_s,
                              gap_before=item.gap_before,
                              timings_ms={"capture": (item.admitted_s - item.origin_s) * 1e3,
                                          "queue": (item.sent_s - item.admitted_s) * 1e3})
        self.pool.release(slot)
        if not self.order.done(seq, result):
            self._drop(seq, "features", "late")

    def _on_lost(self, seqs: list[int], reason: str) -> None:
        for seq in seqs:
            self._drop(seq, "features", reason)

    def _to_sink(self, result: FrameResult) -> None:
        with self._items_lock:
            if self._items.pop(result.seq, None) is None:
                return
        if self.tracker is not None and self.track_stats is not None:
            result.track = self.tracker.update(result.detection, result.frame.timestamp_us / 1e6)
            self.track_stats.record(result.detection, result.track)
        self.ledger.advance(result.seq, "sink")
        for old in self.outq.put(result, self._abort):
            self.ledger.drop(old.seq, "sink", "queue_full" if old is not result else "shutdown")

    # ---------------------------------------------------------------- sink
    def _sink_loop(self) -> None:
        failure = getattr(self.viewer, "failure", None)  # an offering viewer whose output can fail
        # lossless: the viewer's file is an output like the results, so a slow (niced, busy) viewer is waited for
        block_s = self.cfg.pipeline.finish_timeout_s if self.policy == "lossless" else 0.0
        while True:
            result = self.outq.get(POLL_S)
            if result is None:
                if self._abort.is_set() or (self._collect_done.is_set() and len(self.outq) == 0):
                    if self.inline_viewer is not None:
                        self._flush_inline(self.inline_viewer)
                    return
                continue
            if not self._write(result):
                continue
            self.ledger.deliver(result.seq)
            self.stats.record(result.timings_ms)
            if self.viewer is not None and not self.viewer.offer(result, block_s, self._abort.is_set):
                self.ledger.skip_viewer(result.seq, result.frame.frame_counter, "blocked")
            if failure is not None and (failed := failure()) is not None:
                self._output_failed(*failed)
            for live in self.live_viewers:
                if not live.offer(result, 0.0, self._abort.is_set):
                    self.ledger.skip_viewer(result.seq, result.frame.frame_counter, live.drop_reason)

    def _write_outputs(self, result: FrameResult) -> None:
        """Hand the result to every writer whose output has not failed; an OSError (a full disk, a permission)
        fails that output once (_output_failed), the frame goes on to the others."""
        for write in self.writers:
            if write in self._failed_writers:
                continue
            try:
                write(result)
            except OSError as exc:
                self._failed_writers.add(write)
                self._output_failed(str(getattr(write, "path", write)), exc.strerror or str(exc))

    def _output_failed(self, output: str, why: str) -> None:
        """One line for an output that failed; /healthz reports degraded, /metrics and the summary name it."""
        log.error("output %s failed: %s; it is not written any more (the pipeline goes on)", output, why)
        self.outputs_failed[output] = why

    def _write(self, result: FrameResult) -> bool:
        """Hand a frame to the inline viewer and the writers; False (the frame ledgered as dropped by the sink
        stage, naming which part failed) if one raised."""
        part = "viewer"
        try:
            if self.inline_viewer is not None:
                t0 = time.perf_counter()
                self.inline_viewer(result)
                result.timings_ms["logging"] = (time.perf_counter() - t0) * 1e3
            part = "writer"
            result.timings_ms["latency"] = (time.monotonic() - result.arrival_s) * 1e3
            self._write_outputs(result)
            return True
        except Exception as exc:
            reason = f"{part}_error: {type(exc).__name__}: {exc}"
            first = reason not in self._sink_errors  # one line per kind of failure, not one per frame
            self._sink_errors.add(reason)
            log.log(logging.ERROR if first else logging.DEBUG, "sink: the %s failed on frame %d: %s%s", part,
                    result.frame.frame_counter, reason, " (the same for later frames is logged at debug)"
                    if first else "", exc_info=log.isEnabledFor(logging.DEBUG))
            self.ledger.drop(result.seq, "sink", reason)
            return False

    @staticmethod
    def _flush_inline(viewer: InlineViewer) -> None:
        """Send what an inline viewer still batches; its failure costs those frames' viewer rows, nothing else."""
        try:
            viewer.flush()
        except Exception:
            log.exception("the viewer failed to send its last frames")

    # ---------------------------------------------------------------- monitoring
    def snapshot(self) -> PipelineSnapshot:
        """Counters, rates, timings and queue depths for /metrics and the run summary."""
        counters = dict(self.source.counters) if self.source is not None else {}
        track = None if self.track_stats is None else self.track_stats.snapshot()
        return monitor.snapshot(self.ledger, self.stats, self.pool,
                                {"dispatch": len(self.inq), "reorder": self.order.pending, "sink": len(self.outq)},
                                counters, self.error, track, self.outputs_failed)


def _safe_counter(frame: Frame) -> int:
    """The frame counter for the ledger (-1 when it is not an integer)."""
    return frame.frame_counter if isinstance(frame.frame_counter, int) else -1

