"""Nose accuracy of a replay or batch run against the inputs' ground truth, from per-frame results records.

Error = Euclidean pixel distance between the detected nose (its refined sub-pixel tip where the record has one, else
the accepted pixel) and the ground-truth nose pixel; a frame counts as found when a nose was detected within
`radius_px` of the truth; the nose track's pixel (while confirmed) is scored the same way beside it. Frames without
ground truth, or whose nose the truth marks not visible (outside the image, occluded), are ignored; frames whose
ground-truth 3-D nose tip is known are also grouped by distance, in the bins of `tofd evaluate`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofd.lab.evaluation import distance_groups
from tofd.outputs import save_figure

RADIUS_PX = 5.0


@dataclass(frozen=True, slots=True)
class Accuracy:
    """Per frame with ground truth: counter, error in pixels (NaN: no detection), detector score (NaN: none), the
    track's error in pixels (NaN: no confirmed track; None: the results carry no track, i.e. no detector) and the
    ground-truth nose distance in metres (NaN: unknown; None: no frame knows its distance)."""

    frame_counter: np.ndarray  # (M,) int
    error_px: np.ndarray  # (M,) float
    score: np.ndarray  # (M,) float
    track_error_px: np.ndarray | None = None  # (M,) float
    radius_px: float = RADIUS_PX
    distance_m: np.ndarray | None = None  # (M,) float; None: no frame knows its distance

    @property
    def found(self) -> int:
        return int(np.count_nonzero(self.error_px <= self.radius_px))

    @property
    def wrong(self) -> int:
        """Frames with a nose reported farther than radius_px from the truth."""
        return int(np.count_nonzero(self.error_px > self.radius_px))

    @property
    def track_found(self) -> int | None:
        return None if self.track_error_px is None else int(np.count_nonzero(self.track_error_px <= self.radius_px))

    @property
    def track_wrong(self) -> int | None:
        return None if self.track_error_px is None else int(np.count_nonzero(self.track_error_px > self.radius_px))

    def line(self) -> str:
        """`nose found N of M within R px; median error E px, max E px` (errors over frames with a detection), then
        `; track found K of M` when the results carry the track."""
        detected = self.error_px[np.isfinite(self.error_px)]
        errors = (f"median error {np.median(detected):.1f} px, max {detected.max():.1f} px" if detected.size
                  else "no detection")
        track = "" if self.track_found is None else f"; track found {self.track_found} of {len(self.error_px)}"
        return f"nose found {self.found} of {len(self.error_px)} within {self.radius_px:g} px; {errors}{track}"

    def counts(self) -> dict:
        """JSON-ready: frames, found, radius, frames with a detection, median and max error (px, over frames with a
        detection; None if none)."""
        detected = self.error_px[np.isfinite(self.error_px)]
        return {"frames": len(self.error_px), "found": self.found, "radius_px": self.radius_px,
                "detected": int(detected.size),
                "median_error_px": round(float(np.median(detected)), 3) if detected.size else None,
                "max_error_px": round(float(detected.max()), 3) if detected.size else None}

    def to_dict(self) -> dict:
        """counts(), the line, and counts() per distance bin ("0.35": ...; empty when no distance is known)."""
        return {**self.counts(), "line": self.line(),
                "per_distance": {f"{d:.2f}": a.counts() for d, a in self.per_distance().items()}}

    def per_distance(self) -> dict[float, Accuracy]:
        """The frames of known distance by tofd.lab.evaluation.distance_groups (the bins of `tofd evaluate`)."""
        if self.distance_m is None:
            return {}
        return {b: self._subset(index) for b, index in distance_groups(self.distance_m).items()}

    def _subset(self, index: np.ndarray) -> Accuracy:
        return Accuracy(self.frame_counter[index], self.error_px[index], self.score[index],
                        None if self.track_error_px is None else self.track_error_px[index], self.radius_px,
                        None if self.distance_m is None else self.distance_m[index])


def accuracy_table(report: dict) -> str:
    """Text of an Accuracy.to_dict(): found / frames, median and max error (px), overall then per distance bin."""
    lines = [f"{'distance':>9}{'found':>13}{'median px':>11}{'max px':>9}"]
    for label, d in [("all", report), *((f"{k} m", v) for k, v in report["per_distance"].items())]:
        median, worst = (f"{d[k]:.1f}" if d[k] is not None else "-" for k in ("median_error_px", "max_error_px"))
        found = f"{d['found']} / {d['frames']}"
        lines.append(f"{label:>9}{found:>13}{median:>11}{worst:>9}")
    return "\n".join(lines)


def accuracy_from_records(records: Iterable[dict], radius_px: float = RADIUS_PX) -> Accuracy | None:
    """The accuracy over per-frame results records (tofd.service.pipeline.results.result_record, or batch rows)
    that carry ground truth; None when none does."""
    counters, errors, scores, track_errors, distances = [], [], [], [], []
    tracked = True
    for rec in records:
        truth = rec.get("ground_truth_px")
        if truth is None or rec.get("ground_truth_visible") is False:
            continue
        xyz = rec.get("ground_truth_xyz_m")
        track = rec.get("track")
        tracked = tracked and track is not None
        counters.append(rec["frame_counter"])
        errors.append(_error_px(rec.get("tip_px") or rec.get("nose_px"), truth))
        scores.append(rec["score"] if rec.get("score") is not None else np.nan)
        track_errors.append(_error_px(track["nose_px"], truth) if track is not None else np.nan)
        distances.append(float(np.linalg.norm(xyz)) if xyz is not None else np.nan)
    if not counters:
        return None
    distance = np.array(distances, float)
    return Accuracy(np.array(counters), np.array(errors, float), np.array(scores, float),
                    np.array(track_errors, float) if tracked else None, radius_px,
                    distance if np.isfinite(distance).any() else None)


def _error_px(nose: list[float] | None, truth: list[float]) -> float:
    """Pixel distance of a reported nose from the truth (NaN: none reported)."""
    return float(np.hypot(nose[0] - truth[0], nose[1] - truth[1])) if nose is not None else np.nan


def accuracy_from_results(path: str | Path, radius_px: float = RADIUS_PX) -> Accuracy | None:
    """The accuracy over the frames of a results .jsonl that carry ground truth; None when none does."""
    with Path(path).open() as fh:
        return accuracy_from_records((json.loads(line) for line in fh), radius_px)


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
