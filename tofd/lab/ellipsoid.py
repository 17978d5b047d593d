"""A learned alternative to the detector's box: the ellipsoid of the nose pixels' log10 features.

The box (tofd.algorithm.detector.box) bounds each feature on its own; the ellipsoid is the Gaussian fit of the nose
pixels' feature vectors, so features that vary together along the face (e.g. the same eccentricity at two bands)
are bounded along their joint direction. A pixel's distance is its Mahalanobis distance from the nose pixels'
mean: like the box distance, the smallest scale whose ellipsoid holds it, and +inf where a feature is NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_VARIANCE = 1e-6  # log10 units squared, added to the covariance's diagonal: identical samples stay usable


@dataclass(frozen=True, slots=True)
class Ellipsoid:
    """Mean (k,) and inverse covariance (k, k) of log10 feature vectors."""

    mean: np.ndarray
    inverse_covariance: np.ndarray

    def distance(self, x: np.ndarray) -> np.ndarray:
        """(...) Mahalanobis distance of log10 feature vectors (..., k) from the mean; +inf where one is NaN."""
        d = np.asarray(x, dtype=np.float64) - self.mean
        squared = np.einsum("...i,ij,...j->...", d, self.inverse_covariance, d)
        return np.where(np.isnan(squared), np.inf, np.sqrt(np.maximum(squared, 0.0)))


def learn_ellipsoid(samples: np.ndarray) -> Ellipsoid:
    """The Gaussian fit of positive samples (N, k) (rows with a NaN left out); ValueError with fewer than k + 1."""
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 2:
        raise ValueError(f"samples must be (N, k), got {samples.shape}")
    samples = samples[np.all(np.isfinite(samples), axis=1)]
    k = samples.shape[1]
    if len(samples) < k + 1:
        raise ValueError(f"{len(samples)} finite positive samples: an ellipsoid in {k} features needs {k + 1}")
    covariance = np.cov(samples, rowvar=False).reshape(k, k) + MIN_VARIANCE * np.eye(k)
    return Ellipsoid(samples.mean(axis=0), np.linalg.inv(covariance))
