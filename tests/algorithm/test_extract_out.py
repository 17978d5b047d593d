"""FeatureExtractor writes its maps into given arrays (a worker's shared-memory slot) as it would into new ones."""

import numpy as np
import pytest

from tofd.algorithm.extract import FeatureExtractor
from tofd.algorithm.features import Eccentricities
from tofd.algorithm.names import MAP_NAMES
from tofd.config import FeatureConfig, SegmentationConfig
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics


def test_maps_written_into_given_arrays_equal_new_ones():
    intr = Intrinsics()
    extractor = FeatureExtractor(intr, FeatureConfig(), SegmentationConfig())
    r = render_face(load_face("lee_perry_smith"), Pose(distance_m=0.5, yaw_deg=10.0), intr, np.random.default_rng(2))
    fresh = extractor(r.range_m, r.amplitude)
    out = {name: np.full(intr.shape, 123.0, np.float32) for name in MAP_NAMES}  # stale values of an earlier frame
    given = extractor(r.range_m, r.amplitude, out=out)
    assert fresh.mask.any()
    for name in MAP_NAMES:
        assert given.maps[name] is out[name]
        np.testing.assert_array_equal(out[name], fresh.maps[name])  # same computation, NaN where it was stale
        assert np.all(np.isnan(out[name][~fresh.mask]))


def test_out_arrays_of_the_wrong_kind_are_refused():
    with pytest.raises(ValueError, match="out: maps must be C-contiguous float32"):
        Eccentricities.empty((4, 5), out=(np.zeros((4, 5), np.float32), np.zeros((4, 5), np.float64)))
    with pytest.raises(ValueError, match="out: maps must be C-contiguous float32"):
        Eccentricities.empty((4, 5), out=(np.zeros((4, 5), np.float32), np.zeros((5, 8), np.float32)[:4, ::2][:, :5]))
