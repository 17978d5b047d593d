"""Rerun logging in its own process, behind a bounded hand-off, so that a stalled viewer can be abandoned.

Rerun's log and flush calls block for as long as a connected receiver does not read (see
/work/shared/design/rerun_notes.md), and the SDK offers no "drop instead of block". So the RecordingStream
lives in a child process (which also keeps its CPU off the feature workers' GIL, and runs at a lower priority
than they do: VIEWER_NICE): the parent copies each delivered frame into one of `queue_frames` shared-memory
slots and sends its header (wire.py); the child logs it and frees the slot (a semaphore counts the free ones;
the child takes frames in order, so the parent fills the slots round-robin). When no slot is free the frame is
refused (the caller ledgers it as a viewer drop). close() asks the child to flush and exit and SIGKILLs it at
the deadline: nothing in the parent ever waits on Rerun, and the pipe never fills (at most `queue_frames` small
headers are in it).

Protocol: parent -> child, one JSON header per frame (wire.py) or b"close"; child -> parent, one JSON
ViewerStatus once at start (ready, with the web viewer's address, or error), one if a "save" sink's file stops
being written (failed) and one at the end (closed).
"""

from __future__ import annotations

import errno
import json
import logging
import multiprocessing as mp
import os
import shutil
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import replace
from multiprocessing.connection import Connection
from multiprocessing.synchronize import Semaphore
from pathlib import Path
from typing import NotRequired, Protocol, TypedDict

from tofd.config import Config, config_from_dict, config_table
from tofd.outputs import finish_output, temp_path
from tofd.process_setup import child_environment, keep_arrays_on_the_heap
from tofd.service.lifeline import die_with_parent
from tofd.service.pipeline.results import FrameResult
from tofd.service.pipeline.slots import SlotRing
from tofd.service.signals import children_start, ignore_in_child
from tofd.service.summary import ViewerReport
from tofd.service.viewer import wire
from tofd.service.viewer.logger import RerunLogger
from tofd.service.viewer.rotation import FileRotation
from tofd.service.viewer.targets import QUIET_NO_FOOTER, RerunTarget, ViewerError

log = logging.getLogger(__name__)

CLOSE = b"close"
POLL_S = 0.1  # seconds between checks of a start's `cancelled`
IDLE_FLUSH_S = 0.25  # the viewer process sends its waiting batch after this long without a new frame
SINK_CHECK_S = 6.0  # seconds between checks that a "save" sink's file grows (Rerun writes it at least every 5 s)
SINK_FLUSH_TIMEOUT_S = 5.0  # a file sink that cannot write what it was given in this long has failed
FULL_DISK_BYTES = 1 << 20  # a failed file sink's disk with less free space than this was full
FILE_SINK_LOG = "re_log_encoding::rrd=off,re_sdk::recording_stream=off"
"""Added to RUST_LOG (default "warn") of a "save" sink's viewer process: the SDK's own lines about its file are off
(no warning that a live file has no footer; a failed file is reported by tofd, once)."""
VIEWER_NICE = 10  # the viewer process's niceness: on busy cores the feature workers go first


class ViewerClosed(TypedDict):
    frames: int  # frames logged
    errors: int  # frames Rerun refused


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


class RerunBackend:
    """The Rerun stream of a viewer process: RerunTarget (where it goes) and RerunLogger (what it shows); a "save"
    sink with a size or time limit moves on to the next file segment when it is reached (rotation.py). `path`: the
    file a "save" sink writes now (None for other sinks)."""

    def __init__(self, cfg: Config, sink: str, batch_frames: int, footer: bool):
        self.cfg, self.sink, self.batch_frames, self.footer = cfg, sink, batch_frames, footer
        self.rotation = FileRotation(cfg.rerun) if FileRotation.wanted(cfg.rerun, sink, footer) else None
        self.recording_id = str(uuid.uuid4())  # one recording over every segment
        self._open(None if self.rotation is None else self.rotation.segment())
        self.web_url = self.target.web_url

    def _open(self, path: Path | None) -> None:
        self.target = RerunTarget(self.cfg.rerun, self.sink, self.cfg.intrinsics.shape, footer=self.footer,
                                  path=None if path is None else str(path), recording_id=self.recording_id)
        self.logger = RerunLogger(self.target.rec, self.cfg.intrinsics, self.cfg.rerun.point_cloud, self.batch_frames)
        self.path = None if self.sink != "save" else path or Path(self.cfg.rerun.path)

    def __call__(self, r: FrameResult) -> None:
        if self.rotation is not None and self.rotation.due():  # before the frame: a segment never ends up empty
            self.logger.flush()
            self.target.close(self.cfg.pipeline.shutdown_timeout_s)
            self._open(self.rotation.advance())
        self.logger(r)

    def flush(self) -> None:
        self.logger.flush()

    def close(self, timeout_s: float) -> None:
        self.target.close(timeout_s)


OpenBackend = Callable[[Config, str, int, bool], ViewerBackend]
"""Builds a viewer process's backend from (config, sink, frames per send, footer); a module-level function, so
that the spawned child can be handed it."""


def viewer_main(open_backend: OpenBackend, cfg_table: dict, sink: str, batch_frames: int, footer: bool,
                parent_pid: int, frames: Connection, status: Connection, slots: tuple[str, int],
                free: Semaphore) -> None:
    """Entry point of the viewer process: log every frame it is sent to open_backend(...) until CLOSE or the
    pipe closes, freeing its slot (`slots`: the ring's name and size) after; what waits in the backend's batch
    is sent when no frame came for IDLE_FLUSH_S, and at the end."""
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
    failed, checked_s, size_seen, logged_seen = False, time.monotonic(), -1, 0

    rerun_file = target if isinstance(target, RerunBackend) and sink == "save" else None

    def file_sink_failed(closing: bool = False) -> bool:
        """For a "save" sink, at most every SINK_CHECK_S (and when `closing`): whether Rerun's file writer has
        stopped. It says so only on its own stderr, so: a file that did not grow while frames were logged, or a
        full disk, is asked for a bounded flush, and one that cannot finish it has failed; the parent is told."""
        nonlocal failed, checked_s, size_seen, logged_seen
        if rerun_file is None or rerun_file.path is None or failed or (
                not closing and time.monotonic() - checked_s < SINK_CHECK_S):
            return failed
        checked_s, path = time.monotonic(), rerun_file.path
        try:
            size = os.stat(path).st_size
            full = shutil.disk_usage(path.parent).free < FULL_DISK_BYTES
        except OSError:
            size, full = -1, True
        stalled = full or (size == size_seen and logged > logged_seen)
        size_seen, logged_seen = size, logged
        if not stalled:
            return False
        try:
            rerun_file.target.rec.flush(timeout_sec=SINK_FLUSH_TIMEOUT_S)
        except RuntimeError:
            failed = True
            _send_status(status, ViewerStatus(failed=file_problem(str(path))))
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

    while True:
        try:
            if not frames.poll(IDLE_FLUSH_S):
                if not failed:
                    logging_step("batch", target.flush)
                file_sink_failed()
                continue
            header = frames.recv_bytes()
        except (EOFError, OSError):
            break
        if header == CLOSE:
            break
        if file_sink_failed():  # nothing more is logged: it would only pile up in memory
            errors += 1
        else:
            logged += logging_step("frame", lambda h: target(wire.read(h, ring, cfg.intrinsics)), header)
        free.release()  # the logger keeps no view of the slot
    if not failed:
        logging_step("batch", target.flush)
    ring.close()
    file_sink_failed(closing=True)  # bounded: a stopped file writer would hold target.close's flush
    target.close(0.1 if failed else cfg.pipeline.shutdown_timeout_s)  # a failed file takes nothing more
    _send_status(status, ViewerStatus(closed=ViewerClosed(frames=logged, errors=errors)))


def file_problem(path: str) -> str:
    """Why a file output in `path`'s directory most likely stopped (Rerun's file writer does not say)."""
    directory = Path(path).parent
    try:
        if shutil.disk_usage(directory).free < FULL_DISK_BYTES:
            return os.strerror(errno.ENOSPC)
    except OSError as exc:
        return exc.strerror or str(exc)
    if not os.access(directory, os.W_OK):
        return os.strerror(errno.EACCES)
    return "the Rerun file writer stopped"


class ViewerProcess:
    """The parent's handle: start the child (raising ViewerError if its sink cannot start), `offer` frames,
    `close` within a deadline. Use from one thread for offer and one for close. `footer`: whether a "save" sink
    writes Rerun's footer (targets.file_footer). `open_backend`: what the child runs (Rerun by default);
    `name` names the child and the viewer's drops ("blocked" for Rerun, "<name>_blocked" for others)."""

    def __init__(self, cfg: Config, sink: str, batch_frames: int = 1, queue_frames: int = 8,
                 start_timeout_s: float = 30.0, cancelled: Callable[[], bool] = lambda: False, footer: bool = True,
                 open_backend: OpenBackend = RerunBackend, name: str = "rerun"):
        ctx = mp.get_context("spawn")
        self.queue_frames = queue_frames
        self.output = Path(cfg.rerun.path) if sink == "save" else None  # the .rrd, once finished
        # where it grows meanwhile (numbered segments, rotation.py, are written under their own names)
        self._writing = (None if self.output is None or FileRotation.wanted(cfg.rerun, sink, footer)
                         else temp_path(self.output))
        self.failed: str | None = None  # why the output failed, once the child said so
        self._failure_told = False
        if self._writing is not None:
            cfg = replace(cfg, rerun=replace(cfg.rerun, path=str(self._writing)))
        self._ring = SlotRing.create(queue_frames, cfg.intrinsics.shape, wire.PLANES, use="viewer")
        self._free: Semaphore | None = ctx.Semaphore(queue_frames)  # slots the child has finished with
        self._next = 0  # the slot the next frame goes to
        frames_r, self._frames = ctx.Pipe(duplex=False)
        self._status, status_w = ctx.Pipe(duplex=False)
        self.name = name
        self.drop_reason = "blocked" if name == "rerun" else f"{name}_blocked"
        self.process = ctx.Process(target=viewer_main, name=f"tofd-viewer-{name}", daemon=True,
                                   args=(open_backend, config_table(cfg), sink, batch_frames, footer, os.getpid(),
                                         frames_r, status_w, (self._ring.name, queue_frames), self._free))
        if sink == "save":
            quiet = {"RUST_LOG": f"{os.environ.get('RUST_LOG', 'warn')},{FILE_SINK_LOG}"}
        else:
            quiet = {} if footer or "RUST_LOG" in os.environ else {"RUST_LOG": QUIET_NO_FOOTER}
        with child_environment(quiet):
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
        Rerun refused, "unsent": frames handed over but not logged}."""
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
        """The .rrd of a "save" sink under its name if the child finished it, else its readable part under
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
