"""The Rerun backend of a viewer process (tofd.service.viewer.process): where the stream goes (RerunTarget), what it
shows (RerunLogger), file segments (rotation.py), and the health of a "save" sink's file, which Rerun's file writer
reports only on its own stderr."""

from __future__ import annotations

import errno
import os
import shutil
import time
import uuid
from dataclasses import replace
from pathlib import Path

from tofd.config import Config
from tofd.outputs import temp_path
from tofd.service.pipeline.results import FrameResult
from tofd.service.viewer.logger import RerunLogger
from tofd.service.viewer.process import ViewerError
from tofd.service.viewer.rotation import FileRotation
from tofd.service.viewer.targets import QUIET_NO_FOOTER, RerunTarget

SINK_CHECK_S = 6.0  # seconds between checks that a "save" sink's file grows (Rerun writes it at least every 5 s)
SINK_FLUSH_TIMEOUT_S = 5.0  # a file sink that cannot write what it was given in this long has failed
FULL_DISK_BYTES = 1 << 20  # a failed file sink's disk with less free space than this was full
FILE_SINK_LOG = "re_log_encoding::rrd=off,re_sdk::recording_stream=off"
"""Added to RUST_LOG (default "warn") of a "save" sink's viewer process: the SDK's own lines about its file are off
(no warning that a live file has no footer; a failed file is reported by tofd, once)."""


def rerun_output(cfg: Config, sink: str, footer: bool) -> tuple[Path | None, Path | None, Config]:
    """A "save" sink's .rrd (None for other sinks), the temp file it grows in until the viewer process finishes
    it (None where numbered segments of a live file, rotation.py, are written under their own names), and the
    config the viewer process gets (writing the temp file). Raises ViewerError where the output's disk is full
    (check_room)."""
    output = Path(cfg.rerun.path) if sink == "save" else None
    if output is not None:
        check_room(output)
    writing = None if output is None or FileRotation.wanted(cfg.rerun, sink, footer) else temp_path(output)
    if writing is not None:
        cfg = replace(cfg, rerun=replace(cfg.rerun, path=str(writing)))
    return output, writing, cfg


def rerun_log_env(sink: str, footer: bool) -> dict[str, str]:
    """The RUST_LOG of a Rerun viewer process for `sink` (empty: the caller's)."""
    if sink == "save":
        return {"RUST_LOG": f"{os.environ.get('RUST_LOG', 'warn')},{FILE_SINK_LOG}"}
    return {} if footer or "RUST_LOG" in os.environ else {"RUST_LOG": QUIET_NO_FOOTER}


class RerunBackend:
    """The Rerun stream of a viewer process: RerunTarget (where it goes) and RerunLogger (what it shows); a "save"
    sink with a size or time limit moves on to the next file segment when it is reached (rotation.py). `path`: the
    file a "save" sink writes now (None for other sinks)."""

    def __init__(self, cfg: Config, sink: str, batch_frames: int, footer: bool):
        self.cfg, self.sink, self.batch_frames, self.footer = cfg, sink, batch_frames, footer
        self.rotation = FileRotation(cfg.rerun) if FileRotation.wanted(cfg.rerun, sink, footer) else None
        self.recording_id = str(uuid.uuid4())  # one recording over every segment
        self._checked_s, self._size_seen, self._logged_seen = time.monotonic(), -1, 0  # output_problem's checks
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

    def output_problem(self, logged: int, closing: bool) -> str | None:
        """For a "save" sink, at most every SINK_CHECK_S (and when `closing`): why Rerun's file writer stopped,
        if it has. It says so only on its own stderr, so: a file that did not grow while frames were logged, or a
        full disk, is asked for a bounded flush, and one that cannot finish it has failed."""
        if self.sink != "save" or self.path is None or (
                not closing and time.monotonic() - self._checked_s < SINK_CHECK_S):
            return None
        self._checked_s, path = time.monotonic(), self.path
        try:
            size = os.stat(path).st_size
            full = shutil.disk_usage(path.parent).free < FULL_DISK_BYTES
        except OSError:
            size, full = -1, True
        stalled = full or (size == self._size_seen and logged > self._logged_seen)
        self._size_seen, self._logged_seen = size, logged
        if not stalled:
            return None
        try:
            self.target.rec.flush(timeout_sec=SINK_FLUSH_TIMEOUT_S)
        except RuntimeError:
            return file_problem(str(path))
        return None


def check_room(path: Path) -> None:
    """Raise ViewerError (naming `path`) when the disk it goes to has less than FULL_DISK_BYTES free: Rerun's save()
    waits forever for a file writer that could not write the stream's first bytes, so a full disk is refused
    before the viewer process starts."""
    path.parent.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(path.parent).free
    if free < FULL_DISK_BYTES:
        raise ViewerError(f"output {path} failed: {os.strerror(errno.ENOSPC)} ({free // 1024} kB free)")


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
