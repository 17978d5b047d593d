"""The ellipsoid scorer: the Mahalanobis distance of a Gaussian fit, checked against the distribution it came from."""

import numpy as np
import pytest

from tofd.lab.ellipsoid import learn_ellipsoid


def test_distance_is_the_mahalanobis_distance_of_the_sampled_gaussian():
    rng = np.random.default_rng(0)
    covariance = np.array([[0.04, 0.03], [0.03, 0.09]])  # correlated features, log10 units
    mean = np.array([-0.5, 0.2])
    ell = learn_ellipsoid(rng.multivariate_normal(mean, covariance, 20000))
    points = mean + rng.normal(size=(50, 2))
    d = points - mean
    expected = np.sqrt(np.einsum("ni,ij,nj->n", d, np.linalg.inv(covariance), d))
    np.testing.assert_allclose(ell.distance(points), expected, rtol=0.03)
    # along the correlation a point is nearer than the same offset across it
    assert ell.distance(mean + [0.2, 0.2]) < ell.distance(mean + [0.2, -0.2])


def test_nan_features_are_infinitely_far_and_too_few_samples_are_refused():
    ell = learn_ellipsoid(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [np.nan, 0.0]]))
    assert np.isinf(ell.distance(np.array([np.nan, 0.5])))
    assert np.isfinite(ell.distance(np.array([0.5, 0.5])))
    with pytest.raises(ValueError, match="needs 3"):
        learn_ellipsoid(np.array([[0.0, 0.0], [1.0, 1.0], [np.nan, 2.0]]))
