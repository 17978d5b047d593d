"""Boxes in log10 feature space: a pixel is the nose tip iff max_k |x_k - centre_k| / half_width_k <= scale.

x_k = log10(eps_k) of the pixel's eccentricities (they span decades). A pixel's *box distance* is that maximum:
it lies inside the box at scale s iff its box distance <= s, so sweeping s traces the ROC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOG_FLOOR = 1e-30  # eccentricities below this are clipped before log10


def to_log_features(values: np.ndarray) -> np.ndarray:
    """log10 of eccentricities (clipped at LOG_FLOOR); NaN stays NaN."""
    return np.log10(np.maximum(values, LOG_FLOOR))


def require_maps(maps: dict[str, np.ndarray], names: tuple[str, ...]) -> None:
    """Raise KeyError naming the feature maps that were not computed."""
    missing = [n for n in names if n not in maps]
    if missing:
        raise KeyError(f"feature map(s) {', '.join(missing)} not computed")


def stack_features(maps: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """(..., k) log10 feature vectors from named eccentricity maps (each (...)); NaN where any is missing."""
    require_maps(maps, names)
    return to_log_features(np.stack([np.asarray(maps[n], dtype=np.float64) for n in names], axis=-1))


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box in log10 feature space at scale 1: centre +- half_width."""

    features: tuple[str, ...]
    centre: np.ndarray  # (k,) log10 units
    half_width: np.ndarray  # (k,) log10 units, > 0

    def distance(self, x: np.ndarray) -> np.ndarray:
        """(...) box distance of log10 feature vectors (..., k): the smallest scale whose box holds them.

        +inf where a feature is NaN (not foreground / not computed).
        """
        d = np.abs(x[..., 0] - self.centre[0]) / self.half_width[0]
        for k in range(1, x.shape[-1]):  # a column at a time: numpy's max over a short last axis is ~20x slower
            np.maximum(d, np.abs(x[..., k] - self.centre[k]) / self.half_width[k], out=d)
        d[np.isnan(d)] = np.inf
        return d

    def to_dict(self) -> dict:
        return {
            "features": list(self.features),
            "centre_log10": [round(float(c), 6) for c in self.centre],
            "half_width_log10": [round(float(h), 6) for h in self.half_width],
            "low": [float(f"{v:.6g}") for v in 10 ** (self.centre - self.half_width)],
            "high": [float(f"{v:.6g}") for v in 10 ** (self.centre + self.half_width)],
        }

    @classmethod
    def from_dict(cls, d: dict) -> Box:
        features = tuple(d["features"])
        centre = np.asarray(d["centre_log10"], dtype=np.float64)
        half = np.asarray(d["half_width_log10"], dtype=np.float64)
        if not (len(features) == len(centre) == len(half)):
            raise ValueError("features, centre_log10 and half_width_log10 must have the same length")
        if np.any(~np.isfinite(centre)) or np.any(~(half > 0)):
            raise ValueError("centre_log10 must be finite and half_width_log10 positive")
        return cls(features, centre, half)


MIN_HALF_WIDTH = 1e-3  # log10 units; keeps a box of identical samples usable


def learn_box(samples: np.ndarray, features: tuple[str, ...], quantile: float = 0.05) -> Box:
    """The box of the [quantile, 1 - quantile] range of each feature over positive samples (N, k), log10 units.

    Quantiles instead of min/max make the box robust to a few mislabelled or noisy pixels.
    """
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 2 or samples.shape[1] != len(features):
        raise ValueError(f"samples must be (N, {len(features)}), got {samples.shape}")
    if not 0 <= quantile < 0.5:
        raise ValueError(f"quantile must be in [0, 0.5), got {quantile}")
    samples = samples[np.all(np.isfinite(samples), axis=1)]
    if len(samples) == 0:
        raise ValueError("no finite positive samples to learn a box from")
    lo, hi = np.quantile(samples, [quantile, 1 - quantile], axis=0)
    return Box(features, (lo + hi) / 2, np.maximum((hi - lo) / 2, MIN_HALF_WIDTH))


