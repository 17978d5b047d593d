"""Nose accuracy of a replay against the recording's ground truth, from its per-frame results (JSON Lines).

Error = Euclidean pixel distance between the detected and the ground-truth nose pixel; a frame counts as found
when a nose was detected within `radius_px` of the truth. Frames without ground truth are ignored.
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
    """Per frame with ground truth: counter, error in pixels (NaN: no detection) and detector score (NaN: none)."""

    frame_counter: np.ndarray  # (M,) int
    error_px: np.ndarray  # (M,) float
    score: np.ndarray  # (M,) float
    radius_px: float = RADIUS_PX

    @property
    def found(self) -> int:
        return int(np.count_nonzero(self.error_px <= self.radius_px))

    def line(self) -> str:
        """`nose found N of M within R px, median error E px, max E px` (errors over frames with a detection)."""
        detected = self.error_px[np.isfinite(self.error_px)]
        errors = (f"median error {np.median(detected):.1f} px, max {detected.max():.1f} px" if detected.size
                  else "no detection")
        return f"nose found {self.found} of {len(self.error_px)} within {self.radius_px:g} px; {errors}"


def accuracy_from_results(path: str | Path, radius_px: float = RADIUS_PX) -> Accuracy | None:
    """The accuracy over the frames of a results .jsonl that carry ground truth; None when none does."""
    counters, errors, scores = [], [], []
    with Path(path).open() as fh:
        for line in fh:
            rec = json.loads(line)
            truth = rec.get("ground_truth_px")
            if truth is None:
                continue
            nose = rec.get("nose_px")
            counters.append(rec["frame_counter"])
            errors.append(float(np.hypot(nose[0] - truth[0], nose[1] - truth[1])) if nose is not None else np.nan)
            scores.append(rec["score"] if rec.get("score") is not None else np.nan)
    if not counters:
        return None
    return Accuracy(np.array(counters), np.array(errors, float), np.array(scores, float), radius_px)


def plot_accuracy(acc: Accuracy, path: str | Path) -> Path:
    """PNG: nose error (pixels, log scale; the radius dashed) and detector score over the frame counter."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    ax.plot(acc.frame_counter, np.maximum(acc.error_px, 0.1), ".", ms=4)
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
