"""The paper's per-image ROC of a box detector, swept over the box scale, and its equal error rate.

A pixel is classified nose at box scale s iff its box distance (see tofd.algorithm.detector.box_distance) is <= s. So an
image is a detection at scale s iff the smallest box distance among its true nose pixels is <= s, and a false
positive iff the smallest box distance among its other foreground pixels is <= s. With those two minima per
image the whole ROC is a sort and a cumulative count: nothing is recomputed per scale.

Detection rate = share of images with a true nose pixel (images without one, e.g. the nose hidden, don't
count); false-positive rate = share of all images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.detector import PAPER_RULE, Margin


@dataclass(frozen=True, slots=True)
class RocCurve:
    """ROC points over increasing box scale; eer is the interpolated crossing of FPR and 1 - DR."""

    scale: np.ndarray  # (K,) box scale, increasing
    detection_rate: np.ndarray  # (K,) share of images with a true nose pixel that have one classified nose
    false_positive_rate: np.ndarray  # (K,) share of images with a non-nose pixel classified nose
    eer: float  # equal error rate, 0..1
    eer_scale: float  # box scale at the equal error rate
    n_images: int
    n_with_nose: int

    def to_dict(self, points: bool = True) -> dict:
        """JSON-ready: the EER, its scale, the image counts, and the ROC points unless `points` is False."""
        out: dict = {"eer": self.eer, "eer_scale": self.eer_scale, "n_images": self.n_images,
                     "n_with_nose": self.n_with_nose}
        if points:
            out.update(scale=self.scale.tolist(), detection_rate=self.detection_rate.tolist(),
                       false_positive_rate=self.false_positive_rate.tolist())
        return out


def roc_from_min_distances(true_min: np.ndarray, false_min: np.ndarray, has_nose: np.ndarray | None = None) -> RocCurve:
    """ROC from per-image minimal box distances of true nose pixels and of non-nose foreground pixels.

    true_min, false_min: (F,) float; +inf where the image has no such pixel (or none with finite features).
    has_nose: (F,) bool, images that count for the detection rate (default: true_min is finite).
    """
    true_min = np.asarray(true_min, dtype=np.float64)
    false_min = np.asarray(false_min, dtype=np.float64)
    if true_min.shape != false_min.shape or true_min.ndim != 1:
        raise ValueError(f"true_min {true_min.shape} and false_min {false_min.shape} must be equal 1-D shapes")
    has_nose = np.isfinite(true_min) if has_nose is None else np.asarray(has_nose, dtype=bool)
    n, n_nose = len(true_min), int(has_nose.sum())
    finite = np.concatenate([true_min[np.isfinite(true_min)], false_min[np.isfinite(false_min)]])
    scale = np.unique(finite)
    det = np.searchsorted(np.sort(true_min[has_nose]), scale, side="right") / max(n_nose, 1)
    fpr = np.searchsorted(np.sort(false_min), scale, side="right") / max(n, 1)
    if len(scale) == 0 or scale[0] > 0:  # box distances are >= 0: scale 0 accepts nothing here
        scale, det, fpr = (np.concatenate([[0.0], a]) for a in (scale, det, fpr))
    eer, eer_scale = equal_error_rate(scale, det, fpr)
    return RocCurve(scale, det, fpr, eer, eer_scale, n, n_nose)


def equal_error_rate(scale: np.ndarray, detection_rate: np.ndarray, fpr: np.ndarray) -> tuple[float, float]:
    """Interpolated crossing of FPR (rising) and miss rate 1 - DR (falling) along ROC points in scale order.

    If they never cross (FPR stays below the miss rate to the end), the best point's max(FPR, miss) is used.
    """
    miss = 1.0 - np.asarray(detection_rate, dtype=np.float64)
    gap = np.asarray(fpr, dtype=np.float64) - miss  # rises with scale
    crossed = np.flatnonzero(gap >= 0)
    if len(crossed) == 0:
        best = int(np.argmin(np.maximum(fpr, miss)))
        return float(max(fpr[best], miss[best])), float(scale[best])
    b = int(crossed[0])
    if b == 0:
        return float(fpr[0]), float(scale[0])
    a = b - 1
    lam = -gap[a] / (gap[b] - gap[a])
    eer = fpr[a] + lam * (fpr[b] - fpr[a])
    return float(eer), float(scale[a] + lam * (scale[b] - scale[a]))


def margin_scale(true_min: np.ndarray, false_min: np.ndarray, has_nose: np.ndarray, eer_scale: float) -> float:
    """The box scale halfway (geometrically) between the images' noses and everything else, if the box separates them.

    Zero-error interval: every image's nose is in the box (scale >= the largest true_min of the images with a
    nose) and no image's other pixel is (scale < the smallest false_min). Its geometric middle leaves the same
    factor of room on both sides; without such an interval, `eer_scale`.
    """
    true_min, false_min = np.asarray(true_min, np.float64), np.asarray(false_min, np.float64)
    has_nose = np.asarray(has_nose, dtype=bool)
    lo = float(np.max(true_min[has_nose])) if has_nose.any() else 0.0
    hi = float(np.min(false_min)) if false_min.size else np.inf
    if not (0 < lo < hi < np.inf):
        return eer_scale
    return float(np.sqrt(lo * hi))


@dataclass(frozen=True, slots=True)
class Answers:
    """What the detector reports: each image's best candidate pixel, reported or not by the acceptance rule
    (tofd.algorithm.detector.acceptance), as shares of the images; the images where the nose is not found split by
    why (found + rejected + outranked + no_candidate = 1)."""

    scale: float
    found: float  # the reported pixel is a true nose pixel
    wrong: float  # a pixel is reported and it is not a true nose pixel
    rejected: float = 0.0  # a true nose pixel scores best but is not reported (beyond the scale, or the margin)
    outranked: float = 0.0  # another candidate pixel scores better than every true nose pixel
    no_candidate: float = 0.0  # no true nose pixel is a candidate (hidden, or rejected by the candidate tests)

    def to_dict(self) -> dict:
        return {"scale": self.scale, "found_rate": self.found, "wrong_rate": self.wrong,
                "rejected_rate": self.rejected, "outranked_rate": self.outranked,
                "no_candidate_rate": self.no_candidate}


def answers_at(true_min: np.ndarray, false_min: np.ndarray, scale: float, rival: np.ndarray | None = None,
               margin: Margin = PAPER_RULE) -> Answers:
    """Answers from per-image minimal box distances (roc_from_min_distances; a tie goes to the nose) and, for the
    margin test, the box distance of each image's best pixel's rival (inf: none)."""
    true_min, false_min = np.asarray(true_min, np.float64), np.asarray(false_min, np.float64)
    if margin.ratio > 0 and rival is None:
        raise ValueError("the margin test needs each image's rival distance")
    n = max(len(true_min), 1)
    candidate = np.isfinite(true_min)
    nose_first = true_min <= false_min
    best = np.minimum(true_min, false_min)
    reported = margin.accepts(best, np.inf if rival is None else rival, scale) & np.isfinite(best)

    def share(images: np.ndarray) -> float:
        return float(images.sum() / n)

    return Answers(float(scale), share(nose_first & reported), share(~nose_first & reported),
                   share(candidate & nose_first & ~reported), share(candidate & ~nose_first), share(~candidate))
