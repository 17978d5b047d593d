"""Whether a frame's best candidate pixel is reported as the nose.

The paper's rule: its box distance is at most the box scale. With the margin test on, two conditions instead:
its box distance is at most the scale times `scale_factor`, and at most `ratio` times that of its rival, the
best candidate pixel farther than RIVAL_RADIUS_M from it. An unseen nose whose features lie just outside the
training box but far ahead of everything else on the face is accepted; a frame where something elsewhere scores
almost as well is not, however small both distances are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.algorithm.params import DetectorConfig

RIVAL_RADIUS_M = 0.02  # metres: a rival lies farther than this from the best pixel (beyond the nose around it)


@dataclass(frozen=True, slots=True)
class Margin:
    """The margin test (module docstring); ratio 0 switches it off (the paper's rule)."""

    ratio: float = 0.0  # the best pixel's box distance is at most this times its rival's
    scale_factor: float = 1.0  # with the test on, the box scale is the operating scale times this

    @classmethod
    def from_config(cls, detector: DetectorConfig) -> Margin:
        return cls(detector.margin_ratio, detector.margin_scale_factor)

    def accepts(self, score: np.ndarray | float, rival: np.ndarray | float, scale: float) -> np.ndarray:
        """Bool per frame from the best pixel's box distance `score`, its rival's (inf: none) and the box scale."""
        score = np.asarray(score, dtype=np.float64)
        if self.ratio <= 0:
            return score <= scale
        return (score <= scale * self.scale_factor) & (score <= self.ratio * np.asarray(rival, dtype=np.float64))


PAPER_RULE = Margin()
"""No margin test: accepted iff inside the box at the scale."""


def region_bests(distance: np.ndarray, xyz_m: np.ndarray, count: int) -> list[int]:
    """Indices of the best pixel (smallest finite distance) of up to `count` regions: each is the best pixel farther
    than RIVAL_RADIUS_M from all those before it, so the first is the best pixel and the second its rival.
    distance: (P,) per candidate pixel; xyz_m: (P, 3) their points, metres."""
    order = np.argsort(distance, kind="stable")
    order = order[np.isfinite(distance[order])]
    chosen: list[int] = []
    free = np.ones(len(distance), bool)
    for _ in range(count):
        left = order[free[order]]
        if left.size == 0:
            break
        chosen.append(int(left[0]))
        free &= np.sum((xyz_m - xyz_m[left[0]]) ** 2, axis=1) > RIVAL_RADIUS_M**2
    return chosen


def rival_distance(distance: np.ndarray, xyz_m: np.ndarray) -> float:
    """The box distance of the best pixel's rival (region_bests' second region); inf if there is none."""
    regions = region_bests(distance, xyz_m, 2)
    return float(distance[regions[1]]) if len(regions) > 1 else float("inf")
