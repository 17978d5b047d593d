"""ROC and equal error rate of the per-image box detector on constructed cases with known answers."""

import numpy as np
import pytest

from tofd.lab.roc import answers_at, equal_error_rate, margin_scale, roc_from_min_distances


def test_perfect_separation_has_zero_eer():
    true_min = np.array([0.1, 0.2, 0.3, 0.4])
    false_min = np.array([0.5, 0.6, 0.7, 0.8])
    roc = roc_from_min_distances(true_min, false_min)
    assert roc.eer == 0.0
    assert 0.4 <= roc.eer_scale <= 0.5
    assert roc.detection_rate[-1] == 1.0 and roc.false_positive_rate[-1] == 1.0


def test_identical_distributions_cross_at_one_half():
    d = np.arange(1, 11) / 10.0
    roc = roc_from_min_distances(d, d.copy())
    assert roc.eer == pytest.approx(0.5)


def test_interpolated_crossing_known_value():
    # 4 images. Scales: 1 -> DR .25 FPR 0 ; 2 -> DR .25 FPR .5 ; 3 -> DR 1 FPR .5 ...
    # Points (fpr, miss): (0, .75) at 1, (.5, .75) at 2 (gap -.25), (.5, 0) at 3 (gap +.5):
    # crossing at lambda = 1/3 between scales 2 and 3 -> fpr = .5, miss = .75 - .75/3 = .5.
    true_min = np.array([1.0, 3.0, 3.0, 3.0])
    false_min = np.array([2.0, 2.0, 4.0, 4.0])
    roc = roc_from_min_distances(true_min, false_min)
    assert roc.eer == pytest.approx(0.5)
    assert roc.eer_scale == pytest.approx(2 + 1 / 3)


def test_eer_linear_interpolation_between_points():
    # Two ROC points straddling the diagonal: (fpr .1, miss .3) and (fpr .3, miss .1): crossing at .2.
    eer, scale = equal_error_rate(np.array([1.0, 2.0]), np.array([0.7, 0.9]), np.array([0.1, 0.3]))
    assert eer == pytest.approx(0.2) and scale == pytest.approx(1.5)


def test_frames_without_nose_count_only_for_false_positives():
    true_min = np.array([0.1, np.inf, np.inf])
    false_min = np.array([np.inf, 0.2, np.inf])
    roc = roc_from_min_distances(true_min, false_min, has_nose=np.array([True, False, False]))
    assert roc.n_with_nose == 1
    assert roc.eer == 0.0
    # at the largest scale every nose image is detected and one of three images has a false positive
    assert roc.detection_rate[-1] == 1.0 and roc.false_positive_rate[-1] == pytest.approx(1 / 3)


def test_shape_mismatch_is_rejected():
    with pytest.raises(ValueError, match="true_min"):
        roc_from_min_distances(np.zeros(3), np.zeros(4))


def test_margin_scale_is_the_geometric_middle_of_the_zero_error_interval():
    true_min = np.array([0.5, 1.0, np.inf])  # the third image has no nose
    false_min = np.array([4.0, 9.0, 6.0])
    has_nose = np.array([True, True, False])
    assert margin_scale(true_min, false_min, has_nose, eer_scale=1.0) == pytest.approx(2.0)  # sqrt(1 * 4)
    # overlapping: no zero-error interval, the EER scale is kept
    assert margin_scale(np.array([3.0, 1.0]), np.array([2.0, 5.0]), np.array([True, True]), 2.5) == 2.5


def test_answers_follow_the_best_pixel_and_the_scale():
    # image 0: nose best (1 < 3); image 1: other pixel best (2 < 4); image 2: nose best but beyond the scale
    true_min, false_min = np.array([1.0, 4.0, 6.0]), np.array([3.0, 2.0, 8.0])
    a = answers_at(true_min, false_min, scale=5.0)
    assert a.found == pytest.approx(1 / 3) and a.wrong == pytest.approx(1 / 3)
    b = answers_at(true_min, false_min, scale=1.5)  # only image 0's nose is inside
    assert b.found == pytest.approx(1 / 3) and b.wrong == 0.0
    assert answers_at(true_min, false_min, scale=10.0).found == pytest.approx(2 / 3)


def test_misses_split_by_why():
    # 0: found; 1: nose best, beyond the scale; 2: outranked; 3: no candidate nose pixel (inf); 4: nothing at all
    true_min = np.array([1.0, 6.0, 4.0, np.inf, np.inf])
    false_min = np.array([3.0, 8.0, 2.0, 1.0, np.inf])
    a = answers_at(true_min, false_min, scale=5.0)
    assert (a.found, a.rejected, a.outranked, a.no_candidate) == pytest.approx((0.2, 0.2, 0.2, 0.4))
    assert a.wrong == pytest.approx(0.4)  # images 2 and 3 accept another pixel
    assert a.to_dict()["rejected_rate"] == pytest.approx(0.2)


def test_margin_test_reports_clear_winners_only():
    from tofd.algorithm.detector import Margin

    # 0: nose best at 1.2 (beyond scale 1), rival 3.0; 1: nose best at 0.8, rival 1.0 (too close);
    # 2: another pixel best at 1.1, rival 4.0 (a clear, wrong winner); 3: no candidate at all
    true_min, false_min = np.array([1.2, 0.8, 2.0, np.inf]), np.array([3.0, 1.0, 1.1, np.inf])
    rival = np.array([3.0, 1.0, 4.0, np.inf])
    paper = answers_at(true_min, false_min, 1.0)
    assert (paper.found, paper.wrong, paper.rejected) == pytest.approx((0.25, 0.0, 0.25))
    a = answers_at(true_min, false_min, 1.0, rival, Margin(ratio=0.5, scale_factor=1.5))
    assert (a.found, a.wrong, a.rejected, a.outranked, a.no_candidate) == pytest.approx((0.25, 0.25, 0.25, 0.25, 0.25))
    with pytest.raises(ValueError, match="rival"):
        answers_at(true_min, false_min, 1.0, None, Margin(ratio=0.5))
