"""Per-image minima over the pixel table, and shaping the box's half-widths with the training negatives."""

import numpy as np

from tofd.algorithm.detector import VARIANTS, Box, Candidates, learn_box
from tofd.algorithm.names import MAP_NAMES
from tofd.lab.evaluation import FrameSamples, PixelTable, _columns, shape_box
from tofd.lab.roc import roc_from_min_distances

VARIANT = "fft_range_amp"  # 4 features: columns 0, 1, 4, 5 of the samples


def frames(rng, n_frames=200, n_pixels=40, n_true=1, informative_gap=0.02):
    """Frames whose feature 0 separates nose from non-nose pixels (with a small gap) and whose other features are
    pure noise, identical for nose and non-nose pixels."""
    out = []
    for _ in range(n_frames):
        feats = rng.normal(0.0, 1.0, (n_pixels, len(MAP_NAMES))).astype(np.float32)
        tip = np.full(n_pixels, 0.05, np.float32)
        tip[:n_true] = 0.001
        feats[:n_true, 0] = rng.uniform(-0.1, 0.1, n_true)
        feats[n_true:, 0] = np.where(rng.random(n_pixels - n_true) < 0.5, -1, 1) * rng.uniform(
            0.1 + informative_gap, 2.0, n_pixels - n_true)
        border = rng.uniform(0, 0.02, n_pixels).astype(np.float32)
        zeros = np.zeros(n_pixels, np.float32)
        xyz = rng.uniform(-0.1, 0.1, (n_pixels, 3)).astype(np.float32)
        out.append(FrameSamples(feats, tip, border, zeros, zeros, xyz))
    return out


def test_pixel_table_minima_match_a_loop_over_frames():
    rng = np.random.default_rng(0)
    samples = frames(rng, n_frames=12)
    samples[3].tip_distance_m[:] = 0.05  # a frame without nose pixels
    box = Box(VARIANTS[VARIANT], np.zeros(4), np.ones(4))
    table = PixelTable(samples, VARIANT, radius_m=0.015, candidates=Candidates(border_margin_m=0.006))
    true_min, false_min = table.min_distances(box.distance(table.features))
    for i, s in enumerate(samples):
        d = np.where(s.border_m < 0.006, np.inf, box.distance(s.log_features[:, _columns(VARIANT)]))
        true = s.tip_distance_m <= 0.015
        assert true_min[i] == (d[true].min() if true.any() else np.inf)
        assert false_min[i] == (d[~true].min() if (~true).any() else np.inf)
    assert true_min[3] == np.inf


def test_shaping_widens_uninformative_features_and_lowers_the_eer():
    rng = np.random.default_rng(1)
    samples = frames(rng)
    has_nose = np.ones(len(samples), bool)
    table = PixelTable(samples, VARIANT, radius_m=0.015)
    box = learn_box(table.features[table.true], VARIANTS[VARIANT], quantile=0.05)
    before = roc_from_min_distances(*table.min_distances(box.distance(table.features)), has_nose)
    shaped, after = shape_box(box, table, has_nose)
    assert after.eer < before.eer and after.eer <= 0.02  # the noise features no longer cost detections
    assert shaped.half_width[0] == box.half_width[0]  # the first feature's width is the reference
    assert np.all(shaped.half_width[1:] >= 1.4 * box.half_width[1:])  # widened
    np.testing.assert_array_equal(shaped.centre, box.centre)


def test_shaping_keeps_the_quantile_box_when_it_already_separates():
    """Ties at the lowest training EER go to the unchanged box, not to the widths with the largest margin: feature
    0 separates with a gap here, so the noise features' quantile widths already give EER 0 (widening them
    would only enlarge the margin)."""
    rng = np.random.default_rng(2)
    samples = frames(rng, n_frames=100, informative_gap=0.1)
    has_nose = np.ones(len(samples), bool)
    table = PixelTable(samples, VARIANT, radius_m=0.015)
    box = learn_box(table.features[table.true], VARIANTS[VARIANT], quantile=0.05)
    shaped, roc = shape_box(box, table, has_nose)
    assert roc.eer == 0.0
    np.testing.assert_array_equal(shaped.half_width, box.half_width)
