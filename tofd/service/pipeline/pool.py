"""The feature worker pool: start, hand frames to, hear back from, time out and restart worker processes.

The pool owns the workers and the shared-memory slot ring; it knows nothing of ordering or sinks. Events
go to the owner through two callbacks: `on_result(seq, msg)` (the slot is still held; call `release`)
and `on_lost(seqs, reason)` (frames a dead or timed-out worker held; their slots are already free).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import wait as wait_ready

import numpy as np

from tofd.service.pipeline.messages import WorkerReply
from tofd.service.pipeline.slots import SlotRing
from tofd.service.pipeline.worker import WorkerHandle

log = logging.getLogger(__name__)

POLL_S = 0.1  # seconds between checks of wait_ready's give_up
OnResult = Callable[[int, WorkerReply], None]
OnLost = Callable[[list[int], str], None]


class WorkerPool:
    """`n_workers` WorkerHandles over one SlotRing of `n_workers * tasks_per_worker` slots.

    `cap`: frames a worker may hold at once (live: 1, so no frame waits in a pipe behind a slow one).
    Thread-safe: `lock` (a Condition, notified whenever a worker or a slot becomes free) guards the
    workers' pipes and in-flight tables and the ring's bookkeeping.
    """

    def __init__(self, spec: dict, n_workers: int, tasks_per_worker: int, shape: tuple[int, int], cap: int,
                 timeout_s: float, max_failures: int):
        self.ring = SlotRing.create(n_workers * tasks_per_worker, shape)
        spec_json = json.dumps({**spec, "shm": self.ring.name, "n_slots": self.ring.n_slots,
                                "shape": self.ring.shape})
        self.workers = [WorkerHandle(i, spec_json) for i in range(n_workers)]
        self.cap, self.timeout_s, self.max_failures = cap, timeout_s, max_failures
        self.lock = threading.Condition()
        self.restarts = 0
        self.failures = 0  # consecutive deaths without a processed frame
        self.error: str | None = None  # set when the workers cannot start or keep dying

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> None:
        for w in self.workers:
            w.start()

    def wait_ready(self, timeout_s: float, give_up: Callable[[], bool]) -> bool:
        """Wait until every worker reported ready (the caller's collect thread receives the messages), or
        `give_up()` (polled every POLL_S) turns true; whether they all are ready."""
        deadline = time.monotonic() + timeout_s
        with self.lock:
            while not all(w.ready for w in self.workers) and not give_up() and time.monotonic() < deadline:
                self.lock.wait(min(POLL_S, max(0.0, deadline - time.monotonic())))
            return all(w.ready for w in self.workers)

    def stop(self, timeout_s: float = 2.0) -> list[int]:
        """Ask every worker to exit, wait for them together up to `timeout_s`, kill the rest; the indices of
        the workers that had to be killed."""
        deadline = time.monotonic() + timeout_s
        for w in self.workers:
            w.request_stop()
        return [w.index for w in self.workers if not w.stop(max(0.0, deadline - time.monotonic()))]

    def close(self) -> None:
        self.ring.close()

    # ---------------------------------------------------------------- dispatch
    def free_worker(self) -> WorkerHandle | None:
        """The least busy ready worker below `cap` (caller holds `lock`), or None."""
        ready = [w for w in self.workers if w.ready and len(w.inflight) < self.cap]
        return min(ready, key=lambda w: len(w.inflight)) if ready else None

    def wait_free(self, timeout_s: float, abort: threading.Event) -> bool:
        """Wait until a frame can be submitted (a free worker and a free slot: a result being read still holds
        its slot after its worker counts as free) or `abort` is set; whether one can."""
        with self.lock:
            return self.lock.wait_for(
                lambda: (self.free_worker() is not None and self.ring.free > 0) or abort.is_set(), timeout_s)

    def submit(self, seq: int, range_m: np.ndarray, amplitude: np.ndarray) -> bool:
        """Copy a frame into a free slot and send it to the least busy worker; False if none is free."""
        with self.lock:
            worker = self.free_worker()
            slot = self.ring.acquire() if worker is not None else None
            if worker is None or slot is None:  # a worker died between the wait and now
                return False
            views = self.ring.views(slot)
            views["range_m"][...] = range_m
            views["amplitude"][...] = amplitude
            try:
                worker.send(seq, slot)
                return True
            except OSError:  # it died just now; poll() restarts it
                self.ring.release(slot)
                return False

    def release(self, slot: int) -> None:
        with self.lock:
            self.ring.release(slot)
            self.lock.notify_all()

    @property
    def inflight(self) -> int:
        with self.lock:
            return sum(len(w.inflight) for w in self.workers)

    def alive(self) -> int:
        with self.lock:
            return sum(w.alive() for w in self.workers)

    # ---------------------------------------------------------------- collect
    def poll(self, timeout_s: float, on_result: OnResult, on_lost: OnLost, restart: bool) -> None:
        """Receive what the workers sent within `timeout_s`, handle deaths and timeouts (restarting the
        worker if `restart`)."""
        with self.lock:
            conns = {w.results: w for w in self.workers if w.started}
            sentinels = {w.sentinel: w for w in self.workers if w.started}
        ready = wait_ready([*conns, *sentinels], timeout_s)
        for obj in ready:
            if obj in conns:
                self._receive(conns[obj], on_result)
        for obj in ready:  # after its results: _died hands over what it still finished
            if obj in sentinels:
                self._died(sentinels[obj], "worker_died", on_result, on_lost, restart)
        with self.lock:  # the dispatcher adds to `inflight` meanwhile
            overdue = [w for w in self.workers
                       if w.started and w.inflight and w.oldest_task_age_s() > self.timeout_s]
        for w in overdue:
            log.warning("feature worker %d held a frame for more than %.1f s; killing it", w.index, self.timeout_s)
            w.kill()
            self._died(w, "worker_timeout", on_result, on_lost, restart)

    def _receive(self, worker: WorkerHandle, on_result: OnResult) -> None:
        try:
            msg = worker.receive()
        except (EOFError, OSError):
            return  # the sentinel reports the death
        if "ready" in msg:  # WorkerReady
            with self.lock:
                worker.ready = True
                self.lock.notify_all()
            return
        with self.lock:
            worker.inflight.pop(msg["seq"], None)
            if "error" not in msg:
                self.failures = 0
        on_result(msg["seq"], msg)

    def _died(self, worker: WorkerHandle, reason: str, on_result: OnResult, on_lost: OnLost,
              restart: bool) -> None:
        """Hand over what a dead worker finished, report the frames it held, then restart it."""
        with self.lock:
            worker.ready = False  # the dispatcher must not pick it any more
        while worker.results.poll(0):  # results it sent before dying are still good
            try:
                msg = worker.receive()
            except (EOFError, OSError):
                break
            if "seq" in msg:
                with self.lock:
                    worker.inflight.pop(msg["seq"], None)
                on_result(msg["seq"], msg)
        worker.join(1.0)
        with self.lock:
            lost = dict(worker.inflight)
            worker.inflight.clear()
            for slot, _ in lost.values():
                self.ring.release(slot)
            self.lock.notify_all()
        on_lost(sorted(lost), reason)
        log.warning("feature worker %d (pid %s) died; %d frame(s) lost", worker.index, worker.pid, len(lost))
        worker.stop(0.1)
        self.failures += 1
        if self.failures > self.max_failures:
            self.error = f"feature workers died {self.failures} times in a row without processing a frame"
            return
        if restart:
            with self.lock:
                worker.start()
                self.restarts += 1
