"""Feature worker processes (multiprocessing "spawn" context) and their parent-side handles.

Protocol: JSON over one-way pipes (tofd.service.pipeline.messages; small messages only, the arrays stay in the
shared-memory SlotRing); the worker exits at the stop message or when the pipe closes.
Workers ignore SIGINT/SIGTERM: the parent decides when they stop (stop message, else SIGKILL).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess

from tofd.drivers.intrinsics import Intrinsics
from tofd.process_setup import THREAD_ENV, child_environment
from tofd.service.pipeline import messages
from tofd.service.pipeline.messages import WorkerReady, WorkerReply, WorkerTask
from tofd.service.signals import children_start, ignore_in_child

KILL_JOIN_S = 1.0  # seconds to wait for a SIGKILLed worker to be reaped


def worker_main(spec_json: str, tasks: Connection, results: Connection) -> None:
    """Entry point of a worker process."""
    from tofd.service.lifeline import die_with_parent

    die_with_parent()  # a kill -9 of the parent leaves no worker behind
    ignore_in_child()
    from tofd.algorithm.detector import NoseModel
    from tofd.config import config_from_dict
    from tofd.process_setup import prepare_compute_process
    from tofd.service.pipeline.slots import SlotRing
    from tofd.service.pipeline.stages import FeatureStage

    prepare_compute_process()
    spec = json.loads(spec_json)
    ring = SlotRing.attach(spec["shm"], spec["n_slots"], tuple(spec["shape"]))
    model = None if spec["model"] is None else NoseModel.from_dict(spec["model"])
    stage = FeatureStage(config_from_dict(spec["config"]), Intrinsics.from_dict(spec["intrinsics"]), model)
    results.send_bytes(messages.encode(WorkerReady(ready=os.getpid())))
    try:
        while True:
            try:
                task = messages.decode_task(tasks.recv_bytes())
            except EOFError:
                break
            if task is None:
                break
            reply = WorkerReply(seq=task["seq"], slot=task["slot"])
            try:
                reply["reply"] = stage.run(ring.views(task["slot"]))
            except Exception as exc:  # a bad frame must not kill the worker; the parent ledgers it
                reply["error"] = f"{type(exc).__name__}: {exc}"
            results.send_bytes(messages.encode(reply))
    finally:
        ring.close()


@dataclass(frozen=True, slots=True)
class _Running:
    """A started worker process and the parent's ends of its pipes."""

    process: BaseProcess
    tasks: Connection
    results: Connection


class WorkerHandle:
    """Parent-side view of one worker: its process, pipes and the frames it holds (seq -> slot)."""

    def __init__(self, index: int, spec_json: str):
        self.index, self._spec_json = index, spec_json
        self._running: _Running | None = None
        self.ready = False
        self.inflight: dict[int, tuple[int, float]] = {}  # seq -> (slot, monotonic send time)
        self.started_s = 0.0

    def start(self) -> None:
        """Spawn the worker process with THREAD_ENV in its environment, so its BLAS/OpenMP are single-threaded
        from the moment they load (before worker_main runs)."""
        ctx = mp.get_context("spawn")
        task_r, task_w = ctx.Pipe(duplex=False)
        result_r, result_w = ctx.Pipe(duplex=False)
        process = ctx.Process(
            target=worker_main, args=(self._spec_json, task_r, result_w), name=f"tofd-worker-{self.index}", daemon=True
        )
        with child_environment(THREAD_ENV), children_start():
            process.start()
        task_r.close()
        result_w.close()
        self._running, self.ready, self.inflight = _Running(process, task_w, result_r), False, {}
        self.started_s = time.monotonic()

    @property
    def started(self) -> bool:
        """Whether a process runs or ran for this handle since the last stop()."""
        return self._running is not None

    def _live(self) -> _Running:
        if self._running is None:
            raise RuntimeError(f"feature worker {self.index} is not started")
        return self._running

    @property
    def results(self) -> Connection:
        """The pipe the worker's messages come from (started workers only)."""
        return self._live().results

    @property
    def pid(self) -> int | None:
        return None if self._running is None else self._running.process.pid

    @property
    def sentinel(self) -> int:
        return self._live().process.sentinel

    def alive(self) -> bool:
        return self._running is not None and self._running.process.is_alive()

    def send(self, seq: int, slot: int) -> None:
        """Hand the frame in `slot` to the worker (raises OSError if the worker is gone)."""
        self._live().tasks.send_bytes(messages.encode(WorkerTask(seq=seq, slot=slot)))
        self.inflight[seq] = (slot, time.monotonic())

    def receive(self) -> WorkerReady | WorkerReply:
        """The next message from the worker (raises EOFError/OSError if it died)."""
        return messages.decode_from_worker(self._live().results.recv_bytes())

    def oldest_task_age_s(self) -> float:
        """Seconds the oldest frame it holds has been with it (the caller holds the pool's lock)."""
        return max((time.monotonic() - t for _, t in self.inflight.values()), default=0.0)

    def kill(self) -> None:
        pid = self.pid
        if self.alive() and pid is not None:
            os.kill(pid, signal.SIGKILL)

    def join(self, timeout_s: float) -> None:
        """Wait up to `timeout_s` for the process to end (a died worker: reap it)."""
        self._live().process.join(timeout_s)

    def request_stop(self) -> None:
        """Ask the worker to exit after the frame it is on (a dead or stuck pipe is ignored)."""
        if self._running is not None:
            try:
                self._running.tasks.send_bytes(messages.STOP)
            except OSError:
                pass

    def stop(self, timeout_s: float) -> bool:
        """Ask the worker to exit, wait up to `timeout_s`, then kill it; close the pipes. False if it had to be
        killed."""
        running = self._running
        if running is None:
            return True
        self.request_stop()
        running.process.join(timeout_s)
        exited = not running.process.is_alive()
        if not exited:
            self.kill()
            running.process.join(KILL_JOIN_S)
        running.tasks.close()
        running.results.close()
        self._running = None
        return exited
