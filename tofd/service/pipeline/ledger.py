"""The drop ledger: every frame that enters the pipeline leaves it exactly once, delivered or dropped.

Frames are tracked by the pipeline's own sequence number (frame counters can repeat after a device
reconnect) and reported by frame counter. A dropped frame is recorded with the stage that dropped it and
why; device-side gaps (counter jumps, reconnects) are recorded separately, since those frames never
reached the host. Frames delivered (results written) whose best-effort viewer logging was skipped are
recorded apart, in `viewer_drops` (stage "viewer", reason e.g. "blocked"), since they did leave.
Invariant, checked by `consistent`: frames_in == frames_out + frames_dropped once nothing
is pending.
"""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import asdict, dataclass
from typing import TypedDict

STAGES = ("capture", "features", "sink")
"""capture: the capture thread; features: the queue to and the worker processes (segmentation, FFT, NFFT,
detection); sink: the queue to and the sink thread (the results writers, metrics and an inline viewer)."""


@dataclass(frozen=True, slots=True)
class Drop:
    """One dropped frame."""

    frame_counter: int
    seq: int  # pipeline sequence number
    stage: str  # one of STAGES: the stage whose input or work lost the frame
    reason: str  # e.g. "superseded", "late", "worker_died", "queue_full", "shutdown", "invalid_frame: ..."


@dataclass(frozen=True, slots=True)
class Gap:
    """Frames the device produced but the host never received (counter jump, reconnect)."""

    after_counter: int  # last frame counter before the gap (-1 = none)
    next_counter: int  # first frame counter after the gap
    kind: str  # "counter_gap" or "reconnect"


class LedgerSummary(TypedDict):
    """DropLedger.summary: the ledger's part of the run summary (JSON)."""

    frames_in: int
    frames_out: int
    frames_dropped: int
    frames_pending: int
    consistent: bool  # frames_in == frames_out + frames_dropped + frames_pending
    dropped_by_stage: dict[str, int]
    drops: list[dict[str, int | str]]  # each Drop's fields
    gaps: list[dict[str, int | str]]  # each Gap's fields
    viewer_dropped: int
    viewer_dropped_by_reason: dict[str, int]


class DropLedger:
    """Thread-safe bookkeeping of frames in, frames out, drops and device gaps."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: dict[int, tuple[int, str]] = {}  # seq -> (frame_counter, current stage)
        self.frames_in = 0
        self.frames_out = 0
        self.drops: list[Drop] = []
        self.gaps: list[Gap] = []
        self.viewer_drops: list[Drop] = []  # delivered frames the viewer did not get
        self._closed = False  # after close(), late reports about frames no longer pending are ignored

    def admit(self, seq: int, frame_counter: int) -> None:
        """A frame entered the pipeline (capture stage)."""
        with self._lock:
            if seq in self._pending:
                raise RuntimeError(f"frame seq {seq} admitted twice")
            self._pending[seq] = (frame_counter, "capture")
            self.frames_in += 1

    def _take(self, seq: int) -> tuple[int, str] | None:
        """Remove a pending frame (caller holds the lock); unknown seqs are a bug unless the ledger is closed."""
        if seq not in self._pending and self._closed:
            return None
        if seq not in self._pending:
            raise RuntimeError(f"frame seq {seq} is not in flight (delivered or dropped twice?)")
        return self._pending.pop(seq)

    def advance(self, seq: int, stage: str) -> None:
        """The frame is now held by `stage` (used to attribute drops at shutdown)."""
        with self._lock:
            if seq in self._pending:
                self._pending[seq] = (self._pending[seq][0], stage)

    def deliver(self, seq: int) -> None:
        """The frame left the last stage (all sinks handled it)."""
        with self._lock:
            if self._take(seq) is not None:
                self.frames_out += 1

    def drop(self, seq: int, stage: str, reason: str) -> None:
        """The frame was dropped by `stage` for `reason`."""
        if stage not in STAGES:
            raise ValueError(f"stage: {stage!r} is not one of {STAGES}")
        with self._lock:
            taken = self._take(seq)
            if taken is not None:
                self.drops.append(Drop(taken[0], seq, stage, reason))

    def drop_pending(self, reason: str) -> int:
        """Drop every frame still in flight (at a forced shutdown), each at the stage that held it."""
        with self._lock:
            pending, self._pending = self._pending, {}
            for seq, (frame_counter, stage) in sorted(pending.items()):
                self.drops.append(Drop(frame_counter, seq, stage, reason))
            return len(pending)

    def close(self) -> None:
        """No frame is in flight any more (call after drop_pending); late reports are ignored from now on."""
        with self._lock:
            self._closed = True

    def skip_viewer(self, seq: int, frame_counter: int, reason: str) -> None:
        """A delivered frame was not logged to the viewer (it lagged or stalled)."""
        with self._lock:
            self.viewer_drops.append(Drop(frame_counter, seq, "viewer", reason))

    def viewer_drops_by(self) -> Counter[str]:
        with self._lock:
            return Counter(d.reason.split(":")[0] for d in self.viewer_drops)

    def mark_gap(self, after_counter: int, next_counter: int, kind: str) -> None:
        with self._lock:
            self.gaps.append(Gap(after_counter, next_counter, kind))

    @property
    def pending(self) -> int:
        with self._lock:
            return len(self._pending)

    @property
    def frames_dropped(self) -> int:
        with self._lock:
            return len(self.drops)

    def drops_by(self) -> Counter[tuple[str, str]]:
        """Number of drops per (stage, reason class), the reason cut at its first ':'."""
        with self._lock:
            return Counter((d.stage, d.reason.split(":")[0]) for d in self.drops)

    def consistent(self) -> bool:
        """frames_in == frames_out + frames_dropped + frames still pending."""
        with self._lock:
            return self.frames_in == self.frames_out + len(self.drops) + len(self._pending)

    def summary(self) -> LedgerSummary:
        """JSON-ready totals, drops by stage and reason, every drop and gap."""
        with self._lock:
            drops, gaps, viewer = list(self.drops), list(self.gaps), list(self.viewer_drops)
            frames_in, frames_out, pending = self.frames_in, self.frames_out, len(self._pending)
        by_stage = Counter(d.stage for d in drops)
        return LedgerSummary(
            frames_in=frames_in, frames_out=frames_out, frames_dropped=len(drops), frames_pending=pending,
            consistent=frames_in == frames_out + len(drops) + pending, dropped_by_stage=dict(sorted(by_stage.items())),
            drops=[asdict(d) for d in drops], gaps=[asdict(g) for g in gaps], viewer_dropped=len(viewer),
            viewer_dropped_by_reason=dict(sorted(Counter(d.reason for d in viewer).items())))
