"""Nose accuracy of a replay against the recording's ground truth, from its per-frame results (JSON Lines).

Error = Euclidean pixel distance between the detected and the ground-truth nose pixel; a frame counts as found
when a nose was detected within `radius_px` of the truth. The nose track's pixel (while confirmed) is scored the same
way beside it. Frames without ground truth are ignored.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofd.outputs import save_figure

RADIUS_PX = 5.0


@dataclass(frozen=True, slots=True)
class Accuracy:
    """Per frame with ground truth: counter, error in pixels (NaN: no detection), detector score (NaN: none) and the
    track's error in pixels (NaN: no confirmed track; None: the results carry no track, i.e. no detector)."""

    frame_counter: np.ndarray  # (M,) int
    error_px: np.ndarray  # (M,) float
    score: np.ndarray  # (M,) float
    track_error_px: np.ndarray | None = None  # (M,) float
    radius_px: float = RADIUS_PX

    @property
    def found(self) -> int:
        return int(np.count_nonzero(self.error_px <= self.radius_px))

    @property
    def track_found(self) -> int | None:
        return None if self.track_error_px is None else int(np.count_nonzero(self.track_error_px <= self.radius_px))

    def line(self) -> str:
        """`nose found N of M within R px; median error E px, max E px` (errors over frames with a detection), then
        `; track found K of M` when the results carry the track."""
        detected = self.error_px[np.isfinite(self.error_px)]
        errors = (f"median error {np.median(detected):.1f} px, max {detected.max():.1f} px" if detected.size
                  else "no detection")
        track = "" if self.track_found is None else f"; track found {self.track_found} of {len(self.error_px)}"
        return f"nose found {self.found} of {len(self.error_px)} within {self.radius_px:g} px; {errors}{track}"


def accuracy_from_results(path: str | Path, radius_px: float = RADIUS_PX) -> Accuracy | None:
    """The accuracy over the frames of a results .jsonl that carry ground truth; None when none does."""
    counters, errors, scores, track_errors = [], [], [], []
    tracked = True
    with Path(path).open() as fh:
        for line in fh:
            rec = json.loads(line)
            truth = rec.get("ground_truth_px")
            if truth is None:
                continue
            counters.append(rec["frame_counter"])
            errors.append(_error_px(rec.get("nose_px"), truth))
            scores.append(rec["score"] if rec.get("score") is not None else np.nan)
            track = rec.get("track")
            tracked = tracked and track is not None
            track_errors.append(_error_px(track["nose_px"], truth) if track is not None else np.nan)
    if not counters:
        return None
    return Accuracy(np.array(counters), np.array(errors, float), np.array(scores, float),
                    np.array(track_errors, float) if tracked else None, radius_px)


def _error_px(nose: list[float] | None, truth: list[float]) -> float:
    """Pixel distance of a reported nose from the truth (NaN: none reported)."""
    return float(np.hypot(nose[0] - truth[0], nose[1] - truth[1])) if nose is not None else np.nan


def plot_accuracy(acc: Accuracy, path: str | Path) -> Path:
    """PNG: nose error of the detection and the track (pixels, log scale; the radius dashed) and detector score over
    the frame counter."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    ax.plot(acc.frame_counter, np.maximum(acc.error_px, 0.1), ".", ms=4, label="detection")
    if acc.track_error_px is not None:
        ax.plot(acc.frame_counter, np.maximum(acc.track_error_px, 0.1), "x", ms=3, color="tab:cyan", label="track")
        ax.legend(fontsize=7, loc="upper right")
    ax.axhline(acc.radius_px, ls="--", color="grey", lw=1)
    ax.set_yscale("log")
    ax.set_ylabel("nose error [px]")
    ax.set_title(acc.line(), fontsize=9)
    bx.plot(acc.frame_counter, acc.score, ".", ms=4, color="tab:orange")
    bx.set_ylabel("score")
    bx.set_xlabel("frame counter")
    fig.tight_layout()
    try:
        return save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)
