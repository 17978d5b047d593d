"""The drop ledger: every frame that enters the pipeline leaves it exactly once, delivered or dropped.

Frames are tracked by the pipeline's own sequence number (frame counters can repeat after a device
reconnect) and reported by frame counter. A dropped frame is recorded with the stage that dropped it and
why; device-side gaps (counter jumps, reconnects) are recorded separately, since those frames never
reached the host. Frames delivered (results written) whose best-effort viewer logging was skipped are
recorded apart, as viewer drops (stage "viewer", reason e.g. "blocked"), since they did leave.
Invariant, checked by `consistent`: frames_in == frames_out + frames_dropped once nothing
is pending.

Drops are kept as ranges (consecutive counters, one stage and reason: a damaged file's million lost frames are one
entry), and at most LISTED ranges of drops, gaps and viewer drops are listed; the totals by stage and reason count
every frame, so a run of months or a file whose counters jump keeps the ledger and its summary small.
"""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import asdict, dataclass
from typing import TypedDict

STAGES = ("capture", "features", "sink")
"""capture: the capture thread; features: the queue to and the worker processes (segmentation, FFT, NFFT,
detection); sink: the queue to and the sink thread (the results writers, metrics and an inline viewer)."""


LISTED = 1000
"""Most ranges of drops (and of gaps, of viewer drops) a ledger lists; later ones are only counted."""


@dataclass(frozen=True, slots=True)
class Drop:
    """Dropped frames: counters frame_counter to frame_counter + frames - 1, lost at one stage for one reason."""

    frame_counter: int
    seq: int  # pipeline sequence number of the first (a range a source rejected at once has only this one)
    stage: str  # one of STAGES: the stage whose input or work lost the frame
    reason: str  # e.g. "superseded", "late", "worker_died", "queue_full", "shutdown", "invalid_frame: ..."
    frames: int = 1


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
    dropped_by_reason: dict[str, int]  # "stage/reason class": frames
    drops: list[dict[str, int | str]]  # each listed Drop range's fields
    drops_unlisted: int  # drops (a frame or a range each) not listed, beyond LISTED
    gaps: list[dict[str, int | str]]  # each listed Gap's fields
    device_gaps: int  # every gap, listed or not
    viewer_dropped: int
    viewer_dropped_by_reason: dict[str, int]


class _Ranges:
    """Drop ranges, the first LISTED of them listed (a drop continuing the last listed range in counter and
    sequence number, for the same stage and reason, extends it), and frames per (stage, reason class) for all of
    them (caller holds the ledger's lock)."""

    def __init__(self) -> None:
        self.listed: list[Drop] = []
        self.unlisted = 0
        self.by: Counter[tuple[str, str]] = Counter()

    def add(self, drop: Drop) -> None:
        self.by[(drop.stage, drop.reason.split(":")[0])] += drop.frames
        last = self.listed[-1] if self.listed else None
        if last is not None and (last.stage, last.reason) == (drop.stage, drop.reason) and \
                drop.frame_counter == last.frame_counter + last.frames and drop.seq == last.seq + last.frames:
            self.listed[-1] = Drop(last.frame_counter, last.seq, last.stage, last.reason, last.frames + drop.frames)
        elif len(self.listed) < LISTED:
            self.listed.append(drop)
        else:
            self.unlisted += 1

    @property
    def frames(self) -> int:
        return sum(self.by.values())


class DropLedger:
    """Thread-safe bookkeeping of frames in, frames out, drops and device gaps."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: dict[int, tuple[int, str]] = {}  # seq -> (frame_counter, current stage)
        self.frames_in = 0
        self.frames_out = 0
        self._drops = _Ranges()
        self._viewer = _Ranges()  # delivered frames the viewer did not get
        self.gaps: list[Gap] = []  # the first LISTED
        self.gap_count = 0
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
                self._drops.add(Drop(taken[0], seq, stage, reason))

    def lost(self, seq: int, frame_counter: int, frames: int, reason: str) -> None:
        """`frames` frames from counter `frame_counter` on entered and were dropped at capture (a source's rejected
        range), under the one sequence number `seq`."""
        with self._lock:
            self.frames_in += frames
            self._drops.add(Drop(frame_counter, seq, "capture", reason, frames))

    def drop_pending(self, reason: str) -> int:
        """Drop every frame still in flight (at a forced shutdown), each at the stage that held it."""
        with self._lock:
            pending, self._pending = self._pending, {}
            for seq, (frame_counter, stage) in sorted(pending.items()):
                self._drops.add(Drop(frame_counter, seq, stage, reason))
            return len(pending)

    def close(self) -> None:
        """No frame is in flight any more (call after drop_pending); late reports are ignored from now on."""
        with self._lock:
            self._closed = True

    def skip_viewer(self, seq: int, frame_counter: int, reason: str) -> None:
        """A delivered frame was not logged to the viewer (it lagged or stalled)."""
        with self._lock:
            self._viewer.add(Drop(frame_counter, seq, "viewer", reason))

    def viewer_drops_by(self) -> Counter[str]:
        with self._lock:
            return Counter({reason: n for (_, reason), n in self._viewer.by.items()})

    def mark_gap(self, after_counter: int, next_counter: int, kind: str) -> None:
        with self._lock:
            self.gap_count += 1
            if len(self.gaps) < LISTED:
                self.gaps.append(Gap(after_counter, next_counter, kind))

    @property
    def pending(self) -> int:
        with self._lock:
            return len(self._pending)

    @property
    def frames_dropped(self) -> int:
        with self._lock:
            return self._drops.frames

    @property
    def drops(self) -> list[Drop]:
        """The listed drop ranges, oldest first."""
        with self._lock:
            return list(self._drops.listed)

    def drops_by(self) -> Counter[tuple[str, str]]:
        """Frames dropped per (stage, reason class), the reason cut at its first ':'."""
        with self._lock:
            return Counter(self._drops.by)

    def consistent(self) -> bool:
        """frames_in == frames_out + frames_dropped + frames still pending."""
        with self._lock:
            return self.frames_in == self.frames_out + self._drops.frames + len(self._pending)

    def summary(self) -> LedgerSummary:
        """JSON-ready totals, frames dropped by stage and reason, the listed drop ranges and gaps."""
        with self._lock:
            drops, gaps, by = list(self._drops.listed), list(self.gaps), Counter(self._drops.by)
            frames_in, frames_out, pending = self.frames_in, self.frames_out, len(self._pending)
            dropped, unlisted, gap_count = self._drops.frames, self._drops.unlisted, self.gap_count
            viewer = Counter({reason: n for (_, reason), n in self._viewer.by.items()})
        by_stage: Counter[str] = Counter()
        for (stage, _), n in by.items():
            by_stage[stage] += n
        return LedgerSummary(
            frames_in=frames_in, frames_out=frames_out, frames_dropped=dropped, frames_pending=pending,
            consistent=frames_in == frames_out + dropped + pending, dropped_by_stage=dict(sorted(by_stage.items())),
            dropped_by_reason={f"{stage}/{reason}": n for (stage, reason), n in sorted(by.items())},
            drops=[asdict(d) for d in drops], drops_unlisted=unlisted, gaps=[asdict(g) for g in gaps],
            device_gaps=gap_count, viewer_dropped=sum(viewer.values()),
            viewer_dropped_by_reason=dict(sorted(viewer.items())))
