"""Feature worker processes (multiprocessing "spawn" context) and their parent-side handles.

Protocol, JSON over one-way pipes (small messages only; the arrays stay in the shared-memory SlotRing):
  worker -> parent  {"ready": pid}                          once, after its plans are built
  parent -> worker  {"seq": n, "slot": k}                   process the frame in slot k
  worker -> parent  {"seq", "slot", "timings_ms", ...}      or {"seq", "slot", "error": "..."}
  parent -> worker  {"stop": true}  (or the pipe closes)    exit
Workers ignore SIGINT/SIGTERM: the parent decides when they stop (stop message, else SIGKILL).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import time
from multiprocessing.connection import Connection

from drivers.intrinsics import Intrinsics
from tofd.algorithm.threads import THREAD_ENV
from tofd.service.signals import children_start, ignore_in_child

KILL_JOIN_S = 1.0  # seconds to wait for a SIGKILLed worker to be reaped


def worker_main(spec_json: str, tasks: Connection, results: Connection) -> None:
    """Entry point of a worker process."""
    from tofd.service.lifeline import die_with_parent

    die_with_parent()  # a kill -9 of the parent leaves no worker behind
    ignore_in_child()
    from tofd.algorithm.detector import NoseModel
    from tofd.algorithm.threads import prepare_compute_process
    from tofd.config import config_from_dict
    from tofd.service.pipeline.slots import SlotRing
    from tofd.service.pipeline.stages import FeatureStage

    prepare_compute_process()
    spec = json.loads(spec_json)
    ring = SlotRing.attach(spec["shm"], spec["n_slots"], tuple(spec["shape"]))
    model = None if spec["model"] is None else NoseModel.from_dict(spec["model"])
    stage = FeatureStage(config_from_dict(spec["config"]), Intrinsics.from_dict(spec["intrinsics"]), model)
    results.send_bytes(json.dumps({"ready": os.getpid()}).encode())
    try:
        while True:
            try:
                msg = json.loads(tasks.recv_bytes())
            except EOFError:
                break
            if msg.get("stop"):
                break
            reply = {"seq": msg["seq"], "slot": msg["slot"]}
            try:
                reply.update(stage.run(ring.views(msg["slot"])))
            except Exception as exc:  # a bad frame must not kill the worker; the parent ledgers it
                reply["error"] = f"{type(exc).__name__}: {exc}"
            results.send_bytes(json.dumps(reply).encode())
    finally:
        ring.close()


class WorkerHandle:
    """Parent-side view of one worker: its process, pipes and the frames it holds (seq -> slot)."""

    def __init__(self, index: int, spec_json: str):
        self.index, self._spec_json = index, spec_json
        self.process: mp.process.BaseProcess | None = None
        self.tasks: Connection | None = None
        self.results: Connection | None = None
        self.ready = False
        self.inflight: dict[int, tuple[int, float]] = {}  # seq -> (slot, monotonic send time)
        self.started_s = 0.0

    def start(self) -> None:
        """Spawn the worker process; THREAD_ENV goes into this process's environment first, which the child
        inherits, so its BLAS/OpenMP are single-threaded from the moment they load (before worker_main runs)."""
        os.environ.update(THREAD_ENV)
        ctx = mp.get_context("spawn")
        task_r, task_w = ctx.Pipe(duplex=False)
        result_r, result_w = ctx.Pipe(duplex=False)
        self.process = ctx.Process(
            target=worker_main, args=(self._spec_json, task_r, result_w), name=f"tofd-worker-{self.index}", daemon=True
        )
        with children_start():
            self.process.start()
        task_r.close()
        result_w.close()
        self.tasks, self.results, self.ready, self.inflight = task_w, result_r, False, {}
        self.started_s = time.monotonic()

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    @property
    def sentinel(self) -> int:
        return self.process.sentinel

    def alive(self) -> bool:
        return self.process is not None and self.process.is_alive()

    def send(self, seq: int, slot: int) -> None:
        """Hand the frame in `slot` to the worker (raises OSError if the worker is gone)."""
        self.tasks.send_bytes(json.dumps({"seq": seq, "slot": slot}).encode())
        self.inflight[seq] = (slot, time.monotonic())

    def receive(self) -> dict:
        """The next message from the worker (raises EOFError/OSError if it died)."""
        return json.loads(self.results.recv_bytes())

    def oldest_task_age_s(self) -> float:
        """Seconds the oldest frame it holds has been with it (the caller holds the pool's lock)."""
        return max((time.monotonic() - t for _, t in self.inflight.values()), default=0.0)

    def kill(self) -> None:
        if self.alive():
            os.kill(self.process.pid, signal.SIGKILL)

    def request_stop(self) -> None:
        """Ask the worker to exit after the frame it is on (a dead or stuck pipe is ignored)."""
        if self.process is not None:
            try:
                self.tasks.send_bytes(b'{"stop": true}')
            except OSError:
                pass

    def stop(self, timeout_s: float) -> bool:
        """Ask the worker to exit, wait up to `timeout_s`, then kill it; close the pipes. False if it had to be
        killed."""
        if self.process is None:
            return True
        self.request_stop()
        self.process.join(timeout_s)
        exited = not self.process.is_alive()
        if not exited:
            self.kill()
            self.process.join(KILL_JOIN_S)
        self.tasks.close()
        self.results.close()
        self.process = None
        return exited
