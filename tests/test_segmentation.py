import numpy as np
import pytest

from drivers.camera import Intrinsics
from tofd import synthetic
from tofd.config import ConfigError, SegmentationConfig, config_from_dict
from tofd.segmentation import largest_component, otsu_threshold, segment

INTR = Intrinsics()


def _scene():
    """A sphere (the 'face') in front of a body-like plane and a far wall, with invalid pixels."""
    wall = synthetic.tilted_plane(INTR, 2.0, 0.0, 0.0)
    body = synthetic.sphere(INTR, 0.65, 0.4, apex_px=(88.0, 150.0))
    head = synthetic.sphere(INTR, 0.5, 0.09)
    scene = head.over(body.over(wall))
    range_m, amp = scene.range_m.copy(), scene.amplitude.copy()
    return head, range_m, amp


def test_otsu_splits_two_clusters():
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.normal(1.0, 0.1, 5000), rng.normal(5.0, 0.5, 1000)])
    assert 1.4 < otsu_threshold(values) < 3.6


def test_face_is_the_nearest_part_and_invalid_pixels_never_foreground():
    head, range_m, amp = _scene()
    # invalid pixels inside the head: NaN, 0, inf range; NaN amplitude
    range_m[72, 80:84] = np.nan
    range_m[70, 88] = 0.0
    range_m[75, 90] = np.inf
    amp[68, 86] = np.nan
    mask = segment(range_m, amp, SegmentationConfig())
    assert mask.dtype == bool and mask.shape == INTR.shape
    assert not mask[72, 80:84].any() and not mask[70, 88] and not mask[75, 90] and not mask[68, 86]
    assert mask[72, 88]  # the apex (nearest point) is foreground
    # everything kept lies on the head, and the range cut keeps its nearest part
    assert np.all(head.mask[mask])
    assert np.nanmax(range_m[mask]) < np.nanmax(range_m[head.mask])
    amp_fg = (amp > 0) & np.isfinite(range_m) & (range_m < 1.9)  # head + body, not the wall
    assert 0.1 * amp_fg.sum() < mask.sum() < 0.35 * amp_fg.sum()


def test_percentile_is_monotone_and_configurable():
    _, range_m, amp = _scene()
    sizes = [segment(range_m, amp, SegmentationConfig(range_percentile=p)).sum() for p in (10.0, 20.0, 40.0)]
    assert sizes[0] < sizes[1] < sizes[2]


def test_largest_component_drops_a_nearer_speck():
    _, range_m, amp = _scene()
    range_m[5:7, 5:7] = 0.3  # a bright near speck far from the head
    amp[5:7, 5:7] = amp.max()
    assert not segment(range_m, amp, SegmentationConfig())[5:7, 5:7].any()
    assert segment(range_m, amp, SegmentationConfig(largest_component=False))[5:7, 5:7].all()


def test_all_invalid_gives_empty_mask():
    nan = np.full(INTR.shape, np.nan, np.float32)
    assert not segment(nan, nan, SegmentationConfig()).any()
    assert not segment(np.zeros(INTR.shape), np.ones(INTR.shape), SegmentationConfig()).any()


def test_largest_component_of_empty_mask():
    assert not largest_component(np.zeros((4, 4), bool)).any()


def test_shape_mismatch_is_named():
    with pytest.raises(ValueError, match="range_m"):
        segment(np.zeros((3, 3)), np.zeros((3, 4)), SegmentationConfig())


def test_config_validation_names_key():
    with pytest.raises(ConfigError, match="segmentation.range_percentile"):
        config_from_dict({"segmentation": {"range_percentile": 0}})
    with pytest.raises(ConfigError, match="segmentation.amplitude_method"):
        config_from_dict({"segmentation": {"amplitude_method": "mean"}})
