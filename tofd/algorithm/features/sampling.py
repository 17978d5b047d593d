"""Whether a camera's pixels at an object's range can carry the NFFT path's band on its grid.

Pixels spaced p metres apart sample at fs = 1/p cycles per metre, so a grid mode k and k - fs fit the same samples.
The fit stays unique on the band (where the filters respond, up to the band edge, tofd.algorithm.band) while no
alias of a band mode falls on the grid, i.e. while grid Nyquist + band edge <= fs on each axis. Past that, the damped
solve shares the surface between aliases and the features shrink while CG still converges.

What this check does not cover: surface detail beyond the pixels' own Nyquist frequency (fs / 2) in point samples
(a rendered mesh's facets) folds into the band too. That depends on the surface, not on the camera and the band; it
adds a sampling-phase dependent error to one frame's values, not a bias (tofd.lab.face_patch measures it), and a
real pixel, which averages over its footprint, suppresses it.
"""

from __future__ import annotations

from tofd.algorithm.params import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.errors import UsageError


class PatchWarning(UserWarning):
    """Points of the mask outside the NFFT patch (FeatureConfig.patch_width_m x patch_height_m about the mask's
    centroid) were left out: their features are NaN."""


class BandWarning(UserWarning):
    """An operator keeps much of its magnitude beyond the config's band edge, where the NFFT fit is damped rather
    than measured: its fields are biased there."""


class SamplingError(UsageError):
    """The pixels at the object's range are too coarse for the band on the NFFT grid (the message says by how much)."""


def farthest_range_m(intrinsics: Intrinsics, cfg: FeatureConfig) -> float:
    """The range in metres beyond which the camera's pixel pitch cannot carry the band on the NFFT grid."""
    edge = cfg.band_edge_per_m
    nyq_x, nyq_y = cfg.grid_nyquist_per_m
    return min(intrinsics.fx / (nyq_x + edge), intrinsics.fy / (nyq_y + edge))


def check_sampling(range_m: float, intrinsics: Intrinsics, cfg: FeatureConfig) -> None:
    """Raise SamplingError unless points at `range_m` (the foreground's RMS range, metres) carry the band."""
    limit = farthest_range_m(intrinsics, cfg)
    if range_m > limit:
        pitch_mm = 1e3 * range_m / min(intrinsics.fx, intrinsics.fy)
        raise SamplingError(
            f"range_m: the foreground at {range_m:.3g} m is sampled every {pitch_mm:.3g} mm, too coarse for the "
            f"band (edge {cfg.band_edge_per_m:.1f} cycles/m) on the NFFT grid (Nyquist "
            f"{max(cfg.grid_nyquist_per_m):.1f} cycles/m); with these intrinsics and features the object must be "
            f"nearer than {limit:.3g} m: mask a nearer object, or lower the band (tuning_frequency_per_m, "
            f"lowpass_sigma_per_m) or grid_size")
