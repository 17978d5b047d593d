"""A viewer backend (Rerun: rerun_sink.py; Foxglove: tofd.service.foxglove.publisher) in its own process, behind a
bounded hand-off, so that a stalled viewer can be abandoned.

A viewer's log and flush calls can block for as long as a connected receiver does not read (Rerun offers no
"drop instead of block"). So the backend lives in a child process (which also keeps its CPU off the feature
workers' GIL, and runs at a lower priority than they do: VIEWER_NICE): the parent copies each delivered frame
into one of `queue_frames` shared-memory slots and sends its header (wire.py); the child logs it and frees the
slot (a semaphore counts the free ones; the child takes frames in order, so the parent fills the slots
round-robin). When no slot is free the frame is refused (the caller ledgers it as a viewer drop). close() asks
the child to flush and exit and SIGKILLs it at the deadline: nothing in the parent ever waits on the viewer, and
the pipe never fills (at most `queue_frames` small headers are in it). This module imports no viewer SDK: the
child loads only its backend's.

Protocol: parent -> child, one header per frame (wire.py) or b"close"; child -> parent, one JSON
ViewerStatus once at start (ready, with the web viewer's address, or error), one if the backend's output file
stops being written (failed) and one at the end (closed).
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import select
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from multiprocessing.synchronize import Semaphore
from pathlib import Path
from typing import NotRequired, Protocol, TypedDict

from tofd.config import Config, config_from_dict, config_table
from tofd.errors import TofdError
from tofd.logs import root_level, setup_logging
from tofd.outputs import finish_output
from tofd.process_setup import child_environment, keep_arrays_on_the_heap
from tofd.service.lifeline import die_with_parent
from tofd.service.pipeline.results import FrameResult
from tofd.service.pipeline.slots import SlotRing
from tofd.service.signals import children_start, ignore_in_child
from tofd.service.summary import ViewerReport
from tofd.service.viewer import wire

log = logging.getLogger(__name__)

CLOSE = b"close"
POLL_S = 0.1  # seconds between checks of a start's `cancelled`
IDLE_FLUSH_S = 0.25  # the viewer process sends its waiting batch after this long without a new frame
VIEWER_NICE = 10  # the viewer process's niceness: on busy cores the feature workers go first
QUEUE_FRAMES = 8  # slots that absorb a viewer's pauses: a lossless run waits beyond them, a live one drops
LIVE_QUEUE_FRAMES = 2  # a watched live viewer's: when it falls behind it shows frames at most this many frames late


def hand_off_frames(policy: str, sink: str) -> int:
    """Slots between the pipeline and a viewer process of `sink` ("save", "web", "spawn", "connect" or "foxglove")
    in a run of `policy`: few for a viewer someone watches live ("latest"), so that one that falls behind gets the
    latest frames rather than a backlog (the frames it cannot take are refused and ledgered); more for a lossless
    run and for a file, the run's record, to which latency does not matter."""
    return LIVE_QUEUE_FRAMES if policy == "latest" and sink != "save" else QUEUE_FRAMES


class ViewerClosed(TypedDict):
    frames: int  # frames logged
    errors: int  # frames the backend refused


class ViewerStatus(TypedDict):
    """A message of the viewer process to its parent: exactly one of the keys."""

    ready: NotRequired[str | None]  # started; the web viewer's address (the "web" sink) or None
    error: NotRequired[str]  # could not start its sink
    failed: NotRequired[str]  # its "save" sink's file stopped being written (why)
    closed: NotRequired[ViewerClosed]  # flushed and about to exit


def _send_status(status: Connection, message: ViewerStatus) -> None:
    status.send_bytes(json.dumps(message).encode())


class ViewerBackend(Protocol):
    """What a viewer process runs: called with each frame, flush() sends what it batches, close() ends it
    within `timeout_s`; `web_url` is where a user looks (None: nowhere to open)."""

    @property
    def web_url(self) -> str | None: ...

    def __call__(self, r: FrameResult) -> None: ...

    def flush(self) -> None: ...

    def close(self, timeout_s: float) -> None: ...

    def output_problem(self, logged: int, closing: bool) -> str | None:
        """Why the backend's output (a file) stopped being written, once it has (None: it has not, or there is
        none); `logged` frames were logged so far, `closing`: the last check."""
        ...


class ViewerError(TofdError, RuntimeError):
    """A viewer that could not be started or reached."""


OpenBackend = Callable[[Config, str, int, bool], ViewerBackend]
"""Builds a viewer process's backend from (config, sink, frames per send, footer); a module-level function, so
that the spawned child can be handed it."""


def viewer_main(open_backend: OpenBackend, cfg_table: dict, sink: str, batch_frames: int, footer: bool,
                parent_pid: int, frames: Connection, status: Connection, slots: tuple[str, int],
                free: Semaphore, log_level: str = "warning") -> None:
    """Entry point of the viewer process: log every frame it is sent to open_backend(...) until CLOSE or the
    pipe closes, freeing its slot (`slots`: the ring's name and size) after; what waits in the backend's batch
    is sent when no frame came for IDLE_FLUSH_S, and at the end; it logs in tofd's format at the parent's
    `log_level`."""
    setup_logging(log_level)
    die_with_parent(parent_pid)
    ignore_in_child()  # the parent decides when we stop
    keep_arrays_on_the_heap()
    os.nice(VIEWER_NICE)  # it waking up to log a frame would otherwise preempt a worker mid-frame
    cfg = config_from_dict(cfg_table)
    ring = SlotRing.attach(slots[0], slots[1], cfg.intrinsics.shape, wire.PLANES)
    try:
        target = open_backend(cfg, sink, batch_frames, footer)
    except Exception as exc:  # reported to the parent as one line
        _send_status(status, ViewerStatus(error=str(exc)))
        return
    _send_status(status, ViewerStatus(ready=target.web_url))
    logged = errors = 0
    failed = False

    def output_failed(closing: bool = False) -> bool:
        """Whether the backend's output has failed (it is asked at most every so often, and when `closing`); the
        parent is told once."""
        nonlocal failed
        if not failed:
            problem = target.output_problem(logged, closing)
            if problem is not None:
                failed = True
                _send_status(status, ViewerStatus(failed=problem))
        return failed

    def logging_step(what: str, step: Callable[..., None], *args: object) -> bool:
        """step(*args), one logger call; a failure is counted and warned about, and the rest goes on."""
        nonlocal errors
        try:
            step(*args)
            return True
        except Exception as exc:
            errors += 1
            if errors <= 3:
                log.warning("viewer: %s not logged: %s: %s", what, type(exc).__name__, exc)
            return False

    incoming = select.poll()  # made once: Connection.poll builds a selector at every call
    incoming.register(frames.fileno(), select.POLLIN)
    while True:
        try:
            if not incoming.poll(IDLE_FLUSH_S * 1e3):
                if not failed:
                    logging_step("batch", target.flush)
                output_failed()
                continue
            header = frames.recv_bytes()
        except (EOFError, OSError):
            break
        if header == CLOSE:
            break
        if output_failed():  # nothing more is logged: it would only pile up in memory
            errors += 1
        else:
            logged += logging_step("frame", lambda h: target(wire.read(h, ring, cfg.intrinsics)), header)
        free.release()  # the logger keeps no view of the slot
    if not failed:
        logging_step("batch", target.flush)
    ring.close()
    output_failed(closing=True)  # bounded: a stopped file writer would hold target.close's flush
    target.close(0.1 if failed else cfg.pipeline.shutdown_timeout_s)  # a failed file takes nothing more
    _send_status(status, ViewerStatus(closed=ViewerClosed(frames=logged, errors=errors)))


class ViewerProcess:
    """The parent's handle: start the child (raising ViewerError if its sink cannot start), `offer` frames,
    `close` within a deadline. Use from one thread for offer and one for close. `open_backend`: what the child runs
    (None: Rerun, rerun_sink.RerunBackend, with its output file, and `footer`: whether a "save" sink writes
    Rerun's footer, targets.file_footer); `name` names the child and the viewer's drops ("blocked" for Rerun,
    "<name>_blocked" for others)."""

    def __init__(self, cfg: Config, sink: str, batch_frames: int = 1, queue_frames: int = QUEUE_FRAMES,
                 start_timeout_s: float = 30.0, cancelled: Callable[[], bool] = lambda: False, footer: bool = True,
                 open_backend: OpenBackend | None = None, name: str = "rerun"):
        env: dict[str, str] = {}
        self.output: Path | None = None  # the backend's output file, once finished
        self._writing: Path | None = None  # where it grows meanwhile, renamed to `output` when the child finished it
        if open_backend is None:
            from tofd.service.viewer.rerun_sink import RerunBackend, rerun_log_env, rerun_output

            open_backend, env = RerunBackend, rerun_log_env(sink, footer)
            self.output, self._writing, cfg = rerun_output(cfg, sink, footer)
        ctx = mp.get_context("spawn")
        self.queue_frames = queue_frames
        self.failed: str | None = None  # why the output failed, once the child said so
        self._failure_told = False
        self._ring = SlotRing.create(queue_frames, cfg.intrinsics.shape, wire.PLANES, use="viewer")
        self._free: Semaphore | None = ctx.Semaphore(queue_frames)  # slots the child has finished with
        self._next = 0  # the slot the next frame goes to
        frames_r, self._frames = ctx.Pipe(duplex=False)
        self._status, status_w = ctx.Pipe(duplex=False)
        self.name = name
        self.drop_reason = "blocked" if name == "rerun" else f"{name}_blocked"
        self.process = ctx.Process(target=viewer_main, name=f"tofd-viewer-{name}", daemon=True,
                                   args=(open_backend, config_table(cfg), sink, batch_frames, footer, os.getpid(),
                                         frames_r, status_w, (self._ring.name, queue_frames), self._free,
                                         root_level()))
        with child_environment(env):
            with children_start():
                self.process.start()
        frames_r.close()
        status_w.close()
        self._lock = threading.Lock()  # the pipe and `_closing`, between offer and close
        self._closing = False
        self.stalled = False  # no slot was free at the last offer
        self.report: ViewerReport = {}
        self.web_url: str | None = None  # the web viewer's address, for the "web" sink
        msg = self._status_message(start_timeout_s, cancelled)
        if msg is None and cancelled():  # a stop signal while it started: nothing to flush, close() says so
            self._release()
            self._discard_output()
            self.report = ViewerReport(exit="cancelled", unsent=0)
            return
        if msg is None or "ready" not in msg:
            self._release()
            self._discard_output()
            raise ViewerError((msg or {}).get("error") or f"the viewer process did not start in {start_timeout_s:g} s")
        self.web_url = msg["ready"]

    def _status_message(self, timeout_s: float,
                        cancelled: Callable[[], bool] = lambda: False) -> ViewerStatus | None:
        """The child's next status message within `timeout_s` (a failure message is noted in `failed` and
        skipped); None if none came, the child died or `cancelled()` (polled every POLL_S) turned true."""
        deadline = time.monotonic() + timeout_s
        try:
            while not cancelled():
                if self._status.poll(min(POLL_S, max(0.0, deadline - time.monotonic()))):
                    message: ViewerStatus = json.loads(self._status.recv_bytes())
                    if "failed" in message:
                        self.failed = message["failed"]
                        continue
                    return message
                if time.monotonic() >= deadline:
                    break
        except (EOFError, OSError):
            pass
        return None

    def offer(self, result: FrameResult, block_s: float = 0.0, cancelled: Callable[[], bool] = lambda: False) -> bool:
        """Hand a frame to the viewer; False (refused) if no slot frees up within `block_s` seconds (or before
        `cancelled()` turns true) or it is closing. Once a frame was refused, later offers do not wait until a slot
        is free again."""
        deadline = time.monotonic() + (0.0 if self.stalled else block_s)
        if self._free is None:  # released
            return False
        while not self._free.acquire(timeout=max(0.0, min(POLL_S, deadline - time.monotonic()))):
            if self._closing or cancelled() or time.monotonic() >= deadline:
                self.stalled = True
                return False
        self.stalled = False
        slot, self._next = self._next, (self._next + 1) % self.queue_frames
        header = wire.write(result, slot, self._ring.views(slot))
        with self._lock:
            if self._closing:
                return False
            try:
                self._frames.send_bytes(header)  # never blocks: at most queue_frames headers wait in the pipe
            except OSError:
                return False  # the child is gone
        return True

    def failure(self) -> tuple[str, str] | None:
        """(output file, why) once, when the child reported that its output failed; else None (never blocks)."""
        with self._lock:
            if self.failed is None and not self._closing:
                try:
                    if self._status.poll(0):
                        message: ViewerStatus = json.loads(self._status.recv_bytes())
                        self.failed = message.get("failed")
                except (EOFError, OSError):
                    pass
            if self.failed is None or self._failure_told:
                return None
            self._failure_told = True
        return str(self.output), self.failed

    def close(self, timeout_s: float, cancelled: Callable[[], bool] = lambda: False) -> ViewerReport:
        """Let the child log what it was handed, flush and exit; SIGKILL it after `timeout_s` or once `cancelled()`
        (polled) turns true. A summary:
        {"exit": "clean" | "killed" | "cancelled" (stopped while starting), "frames": logged, "errors": frames
        the backend refused, "unsent": frames handed over but not logged}."""
        if self.report:  # cancelled at start: the child is gone already
            return self.report
        deadline = time.monotonic() + timeout_s
        with self._lock:
            self._closing = True
            try:
                self._frames.send_bytes(CLOSE)
            except OSError:
                pass  # the child is gone: no status message will come
        msg = self._status_message(max(0.0, deadline - time.monotonic()), cancelled)
        # its interpreter's exit takes seconds on busy cores
        self.process.join(0.0 if cancelled() else max(0.0, deadline - time.monotonic()))
        unsent = self.queue_frames - (self._free.get_value() if self._free is not None else 0)
        if msg is None or "closed" not in msg or self.process.is_alive():
            log.warning("the viewer did not finish in %.1f s (a stalled receiver?); abandoning it", timeout_s)
            self.report = ViewerReport(exit="killed", unsent=unsent)
        else:
            closed = msg["closed"]
            self.report = ViewerReport(exit="clean", frames=closed["frames"], errors=closed["errors"], unsent=unsent)
        self._release()
        self._finish_output()
        return self.report

    def _finish_output(self) -> None:
        """The output file under its name if the child finished it, else its readable part under
        outputs.partial_path (its name in the report's "output", `failed` saying why)."""
        if self.output is None or self._writing is None:
            return
        finished = self.report.get("exit") == "clean" and self.failed is None
        try:
            where = finish_output(self._writing, self.output, finished)
        except OSError as exc:
            self._writing.unlink(missing_ok=True)
            where, self.failed = None, self.failed or exc.strerror or str(exc)
        if not finished:
            self.failed = self.failed or "the viewer did not finish it"
            log.log(logging.INFO if self._failure_told else logging.ERROR, "output %s could not be finished (%s)%s",
                    self.output, self.failed, f"; its readable part is {where}" if where else "")
            self.report["failed"] = self.failed
        self.report["path"] = str(self.output)
        self.report["output"] = None if where is None else str(where)

    def _discard_output(self) -> None:
        if self._writing is not None:
            self._writing.unlink(missing_ok=True)

    def _release(self) -> None:
        """Kill the child if it still runs; close the pipes and unlink the slots."""
        if self.process.is_alive():
            self.process.kill()
        self.process.join(1.0)
        self._frames.close()
        self._status.close()
        self._ring.close()
        # the semaphore is unlinked (and multiprocessing's resource tracker told) when its last reference goes:
        # here, since tofd's service commands end with os._exit, which runs no finalizers
        self._free = None
