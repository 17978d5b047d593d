"""How far a variant's two features can separate the nose at all: optimistic bounds on the per-image EER.

Both bounds fit a classifier to the very frames they score (no held-out data), so they can only flatter the
features; an EER above the goal here means that no detector on them, trained on any data, meets it on such frames.
- best_box_eer: the paper's detector family, an axis-aligned box in log10 (eps0, eps2), centre and aspect searched
  (the ROC sweeps the size);
- likelihood_ratio_eer: any per-pixel classifier, as the ratio of nose and other pixels among each pixel's nearest
  neighbours in feature space.
Neither is the exact optimum (a grid of boxes; a local estimate of the ratio): a cell is out of reach where both
exceed the goal.
Pixels are the candidates of the table (tofd.lab.evaluation.PixelTable), as the detector sees them.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

from tofd.lab.evaluation import PixelTable
from tofd.lab.roc import roc_from_min_distances

CENTRE_OFFSETS_LOG10 = np.round(np.arange(-0.6, 0.61, 0.1), 2)  # box centre: the nose pixels' median plus these
ASPECTS = (0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 3.0, 5.0, 10.0)  # half-width of the second feature / the first
NEIGHBOURS = 16  # pixels whose labels estimate the likelihood ratio at a pixel
PRIOR = 1e-6  # added to both class shares, so a pixel with neighbours of one class only has a finite ratio


def _two_features(table: PixelTable) -> None:
    if table.features.shape[1] != 2:
        raise ValueError(f"the bounds search two features; this table has {table.features.shape[1]}")


def best_box_eer(table: PixelTable, has_nose: np.ndarray) -> float:
    """The lowest per-image EER of any box on the grid of CENTRE_OFFSETS_LOG10 x ASPECTS (NaN: no nose pixel)."""
    _two_features(table)
    nose = table.features[table.true]
    if not len(nose):
        return float("nan")
    median = np.median(nose, axis=0)
    best = 1.0
    for d0, d2 in itertools.product(CENTRE_OFFSETS_LOG10, repeat=2):
        offset = np.abs(table.features - (median + (d0, d2)))
        for aspect in ASPECTS:  # Box.distance with half-widths (1, aspect), the offsets shared by the aspects
            distance = np.maximum(offset[:, 0], offset[:, 1] / aspect)
            best = min(best, roc_from_min_distances(*table.min_distances(distance), has_nose).eer)
    return best


def likelihood_ratio_eer(table: PixelTable, has_nose: np.ndarray, neighbours: int = NEIGHBOURS) -> float:
    """Per-image EER of the pixels' nose / other likelihood ratio, estimated from each pixel's nearest neighbours
    among these same pixels (itself included), in features scaled to unit spread."""
    _two_features(table)
    f = table.features
    finite = np.isfinite(f).all(axis=1)
    if not np.any(finite & table.true):
        return float("nan")
    points = f[finite] / np.maximum(f[finite].std(axis=0), 1e-12)
    true = table.true[finite]
    _, near = cKDTree(points).query(points, k=min(neighbours, len(points)))
    nose = true[near].sum(axis=1) / true.sum()
    other = (~true[near]).sum(axis=1) / max(int((~true).sum()), 1)
    distance = np.full(len(f), np.inf)
    distance[finite] = (other + PRIOR) / (nose + PRIOR)  # small = nose-like, as box distances
    return roc_from_min_distances(*table.min_distances(distance), has_nose).eer
