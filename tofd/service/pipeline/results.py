"""What the pipeline delivers per frame, and the per-frame results file (JSON Lines)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from tofd.algorithm.tracking import TrackState
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.outputs import AtomicFile


@dataclass(slots=True)
class FrameResult:
    """One processed frame: the input, the mask and feature maps, the detection and the stage timings."""

    seq: int  # pipeline sequence number
    frame: Frame
    mask: np.ndarray  # (H, W) bool foreground
    features: dict[str, np.ndarray]  # the computed maps (names.MAP_NAMES) -> (H, W) float32, NaN outside the foreground
    nfft_iterations: int
    nfft_residual: float
    arrival_s: float  # time.monotonic() when the capture thread received the frame
    box: tuple[slice, slice]  # (rows, cols): the mask's segmentation.foreground_box (0:0 if empty); maps NaN outside
    timings_ms: dict[str, float] = field(default_factory=dict)  # keys from stats.TIMED_STAGES
    detection: Any = None  # tofd.algorithm.detector.Detection, or None without a detector model
    track: TrackState | None = None  # the nose track after this frame, or None without a detector model
    gap_before: str = ""  # "counter_gap" or "reconnect" if the device skipped frames just before this one


def finite_or_none(x: float) -> float | None:
    """x, or None where it is NaN or infinite (JSON has no such numbers)."""
    return x if math.isfinite(x) else None


def flat_dict(obj: Any) -> dict[str, Any]:
    """A dataclass whose fields are plain values (numbers, strings, None, tuples of numbers) as a dict of them:
    dataclasses.asdict without its recursive copies, several times as fast (the viewer's wire, every frame)."""
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def box_list(box: tuple[slice, slice]) -> list[int]:
    """A (rows, cols) box as JSON-ready [row start, row stop, col start, col stop]."""
    rows, cols = box
    return [rows.start, rows.stop, cols.start, cols.stop]


def box_from(v: list[int]) -> tuple[slice, slice]:
    """The (rows, cols) box of box_list."""
    return slice(v[0], v[1]), slice(v[2], v[3])


def track_dict(state: TrackState | None) -> dict | None:
    """A TrackState as a JSON-ready dict (the viewer's wire format), or None."""
    return None if state is None else flat_dict(state)


def track_from(d: dict | None) -> TrackState | None:
    """The TrackState of track_dict (vectors back to tuples), or None."""
    if d is None:
        return None

    def vector(v: list[float] | None) -> tuple[float, float, float] | None:
        return None if v is None else (float(v[0]), float(v[1]), float(v[2]))

    return TrackState(status=d["status"], nose_xyz_m=vector(d["nose_xyz_m"]),
                      velocity_m_per_s=vector(d["velocity_m_per_s"]), confidence=float(d["confidence"]),
                      associated=bool(d["associated"]), assisted=bool(d["assisted"]),
                      reacquired=bool(d["reacquired"]), reported=bool(d["reported"]))


def track_px(state: TrackState | None, intrinsics: Intrinsics) -> tuple[float, float] | None:
    """The image pixel (u, v) of a confirmed track's nose, or None (no track, tentative, or behind the camera)."""
    if state is None or not state.reported or state.nose_xyz_m is None or not state.nose_xyz_m[2] > 0:
        return None
    return intrinsics.project_point(state.nose_xyz_m)


def track_record(state: TrackState | None, intrinsics: Intrinsics) -> dict | None:
    """The results file's track: status, confidence, association flags, and, while confirmed, the reported nose
    (pixel, rounded to 0.01 px, and 3-D point and velocity, rounded to 0.01 mm)."""
    if state is None:
        return None
    px = track_px(state, intrinsics)
    reported = px is not None
    return {"status": state.status, "confidence": state.confidence, "associated": state.associated,
            "assisted": state.assisted, "reacquired": state.reacquired,
            "nose_px": [round(c, 2) for c in px] if px is not None else None,
            "nose_xyz_m": [round(c, 5) for c in state.nose_xyz_m] if reported and state.nose_xyz_m else None,
            "velocity_m_per_s": ([round(c, 5) for c in state.velocity_m_per_s]
                                 if reported and state.velocity_m_per_s else None)}


def result_record(r: FrameResult) -> dict:
    """The JSON-ready per-frame record written to the results file: the frame's detection (the accepted pixel and
    its point, and the sub-pixel tip refined from it), and beside it the nose track after this frame (track_record;
    None without a detector model)."""
    det = r.detection
    truth = r.frame.ground_truth
    return {
        "frame_counter": r.frame.frame_counter,
        "timestamp_us": r.frame.timestamp_us,
        "foreground_px": int(np.count_nonzero(r.mask)),
        "nose_px": list(det.nose_px) if det is not None and det.nose_px is not None else None,
        "nose_xyz_m": [round(c, 5) for c in det.nose_xyz_m] if det is not None and det.nose_xyz_m else None,
        "tip_px": [round(c, 2) for c in det.tip_px] if det is not None and det.tip_px else None,
        "tip_xyz_m": [round(c, 5) for c in det.tip_xyz_m] if det is not None and det.tip_xyz_m else None,
        "score": finite_or_none(det.score) if det is not None else None,
        "accepted": bool(det.accepted) if det is not None else None,
        "track": track_record(r.track, r.frame.intrinsics),
        "ground_truth_px": list(truth.nose_px) if truth else None,
        "ground_truth_xyz_m": list(truth.nose_xyz_m) if truth and truth.nose_xyz_m else None,
        "ground_truth_visible": truth.visible if truth else None,
        "nfft_iterations": r.nfft_iterations,
        "timings_ms": {k: round(v, 3) for k, v in r.timings_ms.items()},
    }


class ResultsWriter:
    """Writes one JSON object per delivered frame to a .jsonl file, atomically: lines go (line-buffered, so a
    crash keeps a prefix) to a temp file beside `path` that close() renames over it (tofd.outputs).

    With `loops`, each record carries "loop": 0 for the first pass, incremented whenever the frame counter
    does not increase (a looping replay starting over).
    """

    def __init__(self, path: str | Path, loops: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = AtomicFile(self.path, "w", buffering=1)
        self._loops, self._loop, self._last_counter = loops, 0, -1
        self.failed: OSError | None = None  # why writing stopped (the temp file is gone then)

    def __call__(self, result: FrameResult) -> None:
        record = result_record(result)
        if self._loops:
            if record["frame_counter"] <= self._last_counter:
                self._loop += 1
            self._last_counter = record["frame_counter"]
            record["loop"] = self._loop
        try:
            self._file.write(json.dumps(record) + "\n")
        except OSError as exc:  # a full disk: the file cannot be completed, so none is left behind
            self.failed = exc
            self._file.discard()
            raise

    def close(self) -> None:
        """Rename the complete file into place (nothing when writing failed; OSError if this fails)."""
        if self.failed is None:
            self._file.commit()

    def discard(self) -> None:
        """Remove the temp file: a failed run leaves no results file behind."""
        self._file.discard()
