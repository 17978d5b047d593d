"""Replay of tofd recordings: ReplaySource (a FrameSource) and iter_frames; the replay policy over one
RecordingReader (tofd.drivers.recording.reader): lossless or realtime (times a speed), a counter range, seek and loop.

The recording's head is read once, by the source's reader (`info` is its header); a damaged recording replays
every intact frame and rejects (FrameSource.reject, for the pipeline's drop ledger) frames lost to damage (by
counter), invalid frames (tofd.drivers.frame.frame_problem) and duplicated frames (same counter and device timestamp).
Where the file ends early or has no intact chunk after damage, the source says why (`stopped_reason`,
`stop_detail`, `last_good_counter`, counters["corrupt_tail"]).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

from tofd.drivers.frame import Frame, frame_problem
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.reader import (
    Damage,
    RecordingInfo,
    RecordingReader,
    recording_info,
)
from tofd.drivers.source import DriverError, FrameSource, SourceReport, StopReason

log = logging.getLogger(__name__)



def _check_counter(name: str, value: int | None) -> None:
    if value is not None and (not isinstance(value, int) or value < 0):
        raise ValueError(f"{name}: expected a frame counter >= 0, got {value!r}")


class ReplaySource(FrameSource):
    """Frames of a recording, as a FrameSource.

    mode="lossless": every frame in the range, as fast as the consumer takes them.
    mode="realtime": frames at their recorded pace (host receive times) divided by `speed`; when the
    consumer falls behind, frames whose successor is already due are skipped and counted in
    counters["replay_dropped"].
    The range is the frames with start <= frame_counter < stop (None = open end); `seek` starts the first
    pass at the first frame whose counter is >= seek; `loop` replays the range again from `start` until
    close() (counters["replay_loops"] counts restarts). Iteration always ends at the end of the file
    unless looping. A damaged file replays every intact frame and rejects the lost ones by counter
    ("damaged: ..."); frames that do not fit the recording ("invalid_frame: ...") or repeat an earlier one
    ("duplicate: ...") are rejected, not replayed. When the file ends early or no intact chunk follows the
    damage, `stopped_reason` ("end", "truncated" or "corrupt"), `stop_detail`, `last_good_counter` say where
    it stopped, a warning is logged and counters["corrupt_tail"] is 1.
    The file is opened and its header read once, here: `info` is the header (None if it is damaged:
    `header_problem` says why, and frames are checked against the default intrinsics' shape).
    """

    def __init__(self, path: str | Path, *, mode: Literal["lossless", "realtime"] = "lossless", speed: float = 1.0,
                 loop: bool = False, seek: int | None = None, start: int | None = None,
                 stop: int | None = None) -> None:
        super().__init__()
        if mode not in ("lossless", "realtime"):
            raise ValueError(f"mode: expected 'lossless' or 'realtime', got {mode!r}")
        if not (isinstance(speed, int | float) and math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed: expected a finite factor > 0, got {speed!r}")
        for name, value in (("seek", seek), ("start", start), ("stop", stop)):
            _check_counter(name, value)
        if start is not None and stop is not None and stop <= start:
            raise ValueError(f"stop: must be greater than start ({start}), got {stop}")
        self.path = Path(path)
        self._reader = RecordingReader(self.path)  # fails now on a missing or foreign file
        self.info: RecordingInfo | None = None
        self.header_problem = ""
        try:
            self.info = recording_info(self._reader)
        except DriverError as exc:  # a damaged header: the frames are still checked against the default shape
            self.header_problem = str(exc)
        self._fresh = True  # the reader stands at the first frame of its first pass
        self.shape = ((self.info and self.info.intrinsics) or Intrinsics()).shape
        """(H, W) every replayed frame has (the recording's intrinsics)."""
        self.mode, self.speed, self.loop = mode, float(speed), loop
        self.seek, self.start, self.stop = seek, start, stop
        self.stopped_reason: StopReason | None = None
        self.stop_detail = ""
        self.last_good_counter: int | None = None  # counter of the last frame read intact from the file
        self.frames_read = 0  # intact frames read from the file in the first pass
        self.damage: list[Damage] = []  # damaged stretches skipped in the first pass
        if self.info is not None:
            self.intrinsics, self.settings = self.info.intrinsics, dict(self.info.config or {})

    @property
    def expected_frames(self) -> int | None:
        """The recording's frames per its header (None: no header, or looping)."""
        return None if self.info is None or self.loop else self.info.frame_count

    @property
    def report(self) -> SourceReport:
        return SourceReport(self.stopped_reason, self.stop_detail, self.last_good_counter)

    def counters_reach(self, seek: int) -> tuple[bool, int | None]:
        """Whether a frame of the recording has a counter >= seek, and the last counter read to find out (a pass
        of the source's reader, before iteration, up to that frame)."""
        last = None
        self._reader.rewind()
        self._fresh = False
        for item in self._reader.frames():
            if isinstance(item, Frame):
                if item.frame_counter >= seek:
                    return True, item.frame_counter
                last = item.frame_counter
        return False, last

    def _in_range(self, counter: int) -> bool:
        return (self.start is None or counter >= self.start) and (self.stop is None or counter < self.stop)

    def _pass(self, seek: int | None, first: bool) -> Iterator[Frame]:
        """Valid frames of one pass over the file, within the range, from the first counter >= seek; invalid,
        duplicated and (by counter) lost frames are rejected (FrameSource.reject) in their place."""
        seeking, seen, damage, last = seek is not None, set(), None, None
        reader = self._reader
        if not self._fresh:
            reader.rewind()
        self._fresh = False
        for item in reader.frames():
            if self.closed:
                return
            if isinstance(item, Damage):
                damage = item
                log.warning("%s: damaged bytes %d-%d skipped: %s", self.path, item.start, item.end, item.detail)
                continue
            problem = frame_problem(item, self.shape)
            counter, key = item.frame_counter, (item.frame_counter, item.timestamp_us)
            if problem is None and damage is not None:
                self._reject_lost(last, counter, damage, seek if seeking else None)
                damage = None
            if problem is None and key in seen:
                problem = f"duplicate: frame {counter} at {item.timestamp_us} us was already replayed"
            elif problem is None:
                seen.add(key)
                last = counter
                if first:
                    self.frames_read += 1
                    self.last_good_counter = counter
            else:
                problem = f"invalid_frame: {problem}"
            if seeking and (problem is not None or (seek is not None and counter < seek)):
                continue
            seeking = False
            if not self._in_range(counter):
                continue
            if problem is None:
                yield item
            else:
                self.reject(counter, problem)
        if first:
            self._report(reader)

    def _reject_lost(self, last: int | None, counter: int, damage: Damage, seek: int | None) -> None:
        """Reject, as one range, the frames after counter `last` that `damage` destroyed: one per chunk record it
        held (a tofd recording has one frame per chunk), at most the counters between `last` and `counter` (the
        rest of a larger jump is a device gap, as it is to a reader of the chunk index)."""
        if last is None or counter - last - 1 < 1:
            log.warning("%s: frames lost to the damage at byte %d cannot be counted (counters %s -> %d)",
                        self.path, damage.start, last, counter)
            self.counters["damaged_uncounted"] += 1
            return
        first, end = last + 1, last + 1 + min(damage.chunks, counter - last - 1)
        first = max(first, seek or 0, self.start or 0)
        end = min(end, self.stop if self.stop is not None else end)
        if first < end:
            self.reject(first, f"damaged: bytes {damage.start}-{damage.end}: {damage.detail}", end - first)

    def _report(self, reader: RecordingReader) -> None:
        self.stopped_reason, self.stop_detail = reader.reason, reader.detail
        self.damage = list(reader.damage)
        if reader.reason != "end":
            self.counters["corrupt_tail"] += 1
            log.warning("%s: replayed the readable prefix (%d frames, last frame counter %s); %s: %s",
                        self.path, self.frames_read, self.last_good_counter, reader.reason, reader.detail)

    def _paced(self, frames: Iterator[Frame]) -> Iterator[Frame]:
        """Frames at their recorded pace / speed, skipping those overtaken while the consumer was busy."""
        t0 = r0 = prev_r = 0.0
        current = next(frames, None)
        rebase = True
        while current is not None:
            following = next(frames, None)
            now = time.monotonic()
            r = current.host_monotonic_s
            if rebase or r < prev_r:  # first frame, or recorded time went backwards: restart the clock
                t0, r0, rebase = now, r, False
            prev_r = r
            if following is not None and t0 + (following.host_monotonic_s - r0) / self.speed <= now:
                self.counters["replay_dropped"] += 1
                current = following
                continue
            wait = t0 + (r - r0) / self.speed - now
            if wait > 0 and self._closed.wait(wait):
                return
            yield current
            current = following

    def __iter__(self) -> Iterator[Frame]:
        """The frames (iterate from one thread at a time; close() may come from any thread)."""
        try:
            yield from self._passes()
        finally:
            self._reader.close()

    def _passes(self) -> Iterator[Frame]:
        first = True
        while not self.closed:
            frames = self._pass(self.seek if first else self.start, first)
            if self.mode == "realtime":
                frames = self._paced(frames)
            yielded = False
            for frame in frames:
                if self.closed:
                    return
                yielded = True
                self.counters["frames"] += 1
                yield frame
            if self.closed or not self.loop or (not yielded and not (first and self.seek is not None)):
                return
            first = False
            self.counters["replay_loops"] += 1


def iter_frames(path: str | Path, *, start: int | None = None, stop: int | None = None) -> Iterator[Frame]:
    """Every frame of a recording in order (lossless), e.g. as evaluation input with ground truth."""
    with ReplaySource(path, start=start, stop=stop) as source:
        yield from source
