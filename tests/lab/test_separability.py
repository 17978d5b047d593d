"""The separability bounds: zero where a box separates, chance where nothing does, and a likelihood ratio that
beats every box where the nose sits inside a ring of other pixels."""

import numpy as np
import pytest

from tofd.algorithm.detector import Box, Candidates
from tofd.algorithm.names import MAP_NAMES
from tofd.lab.evaluation import FrameSamples, PixelTable, has_nose
from tofd.lab.roc import roc_from_min_distances
from tofd.lab.separability import best_box_eer, likelihood_ratio_eer

VARIANT = "nfft_range"
COLUMNS = [MAP_NAMES.index(n) for n in ("range_nfft_eps0", "range_nfft_eps2")]


def frames(rng, nose_xy, other_xy, n_frames=60):
    """Frames of one nose pixel and 30 others whose (log eps0, log eps2) are drawn by nose_xy() / other_xy(n)."""
    out = []
    for _ in range(n_frames):
        feats = np.zeros((31, len(MAP_NAMES)), np.float32)
        feats[0, COLUMNS] = nose_xy()
        feats[1:, COLUMNS] = other_xy(30)
        tip = np.full(31, 0.05, np.float32)
        tip[0] = 0.0
        zeros = np.zeros(31, np.float32)
        out.append(FrameSamples(feats, tip, np.full(31, 0.02, np.float32), zeros, zeros, zeros[:, None].repeat(3, 1)))
    return out


def bounds(samples):
    table = PixelTable(samples, VARIANT, 0.015, Candidates())
    with_nose = has_nose(samples, 0.015)
    return table, with_nose, best_box_eer(table, with_nose), likelihood_ratio_eer(table, with_nose)


def test_separable_features_give_zero():
    rng = np.random.default_rng(1)
    nose = lambda: rng.normal((-5.0, -6.0), 0.05)  # noqa: E731
    other = lambda n: rng.normal((-5.0, -6.0), 0.05, (n, 2)) + rng.choice([-1.0, 1.0], (n, 2))  # noqa: E731
    *_, box, ratio = bounds(frames(rng, nose, other))
    assert box == 0.0 and ratio == 0.0


def test_indistinguishable_features_give_chance_or_worse():
    rng = np.random.default_rng(2)
    *_, box, ratio = bounds(frames(rng, lambda: rng.normal(0, 1, 2), lambda n: rng.normal(0, 1, (n, 2))))
    assert box > 0.3  # one nose pixel against 30 alike: the best of many boxes still misses most frames
    assert ratio > 0.3


def test_box_bound_is_no_worse_than_a_given_box_and_the_ratio_beats_boxes_on_a_ring():
    """Nose at the centre of a ring of other pixels, plus others far away: a box around the centre wins only if
    it stays inside the ring; the likelihood ratio needs no such luck."""
    rng = np.random.default_rng(3)

    def other(n):
        angle = rng.uniform(0, 2 * np.pi, n)
        ring = np.stack([np.cos(angle), np.sin(angle)], 1) * rng.uniform(0.3, 0.4, (n, 1))
        return np.where(rng.random((n, 1)) < 0.5, ring, rng.uniform(-3, 3, (n, 2)))

    table, with_nose, box, ratio = bounds(frames(rng, lambda: rng.normal(0, 0.12, 2), other))
    centred = Box(("range_nfft_eps0", "range_nfft_eps2"), np.median(table.features[table.true], 0), np.ones(2))
    given = roc_from_min_distances(*table.min_distances(centred.distance(table.features)), with_nose).eer
    assert box <= given
    assert ratio <= box


def test_four_features_are_refused():
    rng = np.random.default_rng(4)
    samples = frames(rng, lambda: rng.normal(0, 1, 2), lambda n: rng.normal(0, 1, (n, 2)), n_frames=3)
    table = PixelTable(samples, "nfft_range_amp", 0.015, Candidates())
    with pytest.raises(ValueError, match="two features"):
        best_box_eer(table, has_nose(samples, 0.015))
