import dataclasses

import cv2
import numpy as np
import pytest

from tofd.algorithm.segmentation import component_at, fill_holes, otsu_threshold, rotation_to_z, segment, segment_face
from tofd.config import ConfigError, SegmentationConfig, config_from_dict
from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic
from tofd_testing.wide_fov import realsense_like_87deg, sphere_before_wall

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


def test_otsu_of_one_value_or_none_keeps_nothing_above_it():
    assert otsu_threshold(np.full(100, 2.5)) == 2.5
    assert otsu_threshold(np.array([])) == np.inf


def test_a_frame_of_uniform_amplitude_has_no_foreground_and_no_error():
    """No contrast in the amplitude (a blank or saturated frame): an empty mask, not an exception."""
    _, range_m, amp = _scene()
    assert not segment(range_m, np.ones_like(amp), SegmentationConfig(), INTR).any()


RAY_Z = INTR.unit_rays()[..., 2]


def _cap(head, range_m, margin):
    """The analytic answer: the head's pixels within `margin` of its nearest depth (z)."""
    return head.mask & (range_m * RAY_Z <= np.nanmin(head.range_m * RAY_Z) + margin)


def test_face_is_an_iso_range_cap_and_invalid_pixels_never_foreground():
    head, range_m, amp = _scene()
    # invalid pixels inside the head: NaN, 0, inf range; NaN amplitude
    range_m[72, 80:84] = np.nan
    range_m[70, 88] = 0.0
    range_m[75, 90] = np.inf
    amp[68, 86] = np.nan
    cfg = SegmentationConfig()
    mask = segment(range_m, amp, cfg)
    assert mask.dtype == bool and mask.shape == INTR.shape
    assert not mask[72, 80:84].any() and not mask[70, 88] and not mask[75, 90] and not mask[68, 86]
    assert mask[72, 88]  # the apex (nearest point) is foreground
    # everything kept lies on the head, within the depth margin of the apex, and the cap is all there
    assert np.all(head.mask[mask])
    # reference = 1st percentile of the depths: within a few mm of the apex
    assert np.nanmax((range_m * RAY_Z)[mask]) <= np.nanmin(head.range_m * RAY_Z) + cfg.depth_margin_m + 0.003
    cap = _cap(head, range_m, cfg.depth_margin_m) & np.isfinite(range_m) & np.isfinite(amp) & (range_m > 0)
    assert (mask & cap).sum() >= 0.97 * cap.sum()
    assert (mask & ~_cap(head, range_m, cfg.depth_margin_m + 0.003)).sum() == 0


def test_cut_is_a_depth_not_a_pixel_share():
    """The same sphere near and far (with a body that fills more of the image when near): the kept cap
    reaches the same depth behind the apex, the margin, and is the analytic cap."""
    wall = synthetic.tilted_plane(INTR, 2.0, 0.0, 0.0)
    cfg = SegmentationConfig()
    extents = []
    for d in (0.35, 0.7):
        head = synthetic.sphere(INTR, d, 0.09)
        body = synthetic.sphere(INTR, d + 0.15, 0.4, apex_px=(88.0, 150.0))  # shoulders: nearer the frame edge
        scene = head.over(body.over(wall))
        mask = segment(scene.range_m, scene.amplitude, cfg)
        assert np.all(head.mask[mask])
        depth = scene.range_m * RAY_Z
        extents.append(depth[mask].max() - depth[mask].min())
        cap = _cap(head, scene.range_m, cfg.depth_margin_m)
        assert (mask & cap).sum() / (mask | cap).sum() > 0.9
    assert extents[0] == pytest.approx(cfg.depth_margin_m, abs=0.003)
    assert extents[1] == pytest.approx(extents[0], abs=0.002)


def test_margin_is_monotone_and_configurable():
    _, range_m, amp = _scene()
    sizes = [segment(range_m, amp, SegmentationConfig(depth_margin_m=m)).sum() for m in (0.02, 0.04, 0.08)]
    assert sizes[0] < sizes[1] < sizes[2]


def test_noise_does_not_fray_the_border_and_far_outliers_are_dropped():
    head, range_m, amp = _scene()
    noisy = range_m + 0.004 * np.random.default_rng(2).standard_normal(range_m.shape)
    noisy[74, 86] = 1.5  # a flying pixel inside the cap: the median hides it, its own range is beyond the cut
    # margin pinned: a shallower cut meets the sphere where it is flatter, so noise frays it more for any filter;
    # cut along z (no face plane, whose noisy fit tilts it by ~0.5 deg) so that _cap is the exact answer
    cfg = SegmentationConfig(depth_margin_m=0.035, plane_iterations=0)
    plain = dataclasses.replace(cfg, median_px=1, morphology_px=1)
    filtered, raw = segment(noisy, amp, cfg), segment(noisy, amp, plain)
    assert not filtered[74, 86]

    def border(m):
        return int((m & ~cv2.erode(m.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)).sum())

    cap = _cap(head, range_m, cfg.depth_margin_m)
    assert border(filtered) < 0.8 * border(raw)
    assert (filtered ^ cap).sum() < (raw ^ cap).sum()


def test_nearest_component_drops_specks_and_the_farther_object():
    _, range_m, amp = _scene()
    range_m[5:7, 5:7] = 0.3  # a bright near speck far from the head: the median removes it
    amp[5:7, 5:7] = amp.max()
    assert not segment(range_m, amp, SegmentationConfig())[5:7, 5:7].any()
    second = synthetic.sphere(INTR, 0.52 / RAY_Z[30, 20], 0.09, apex_px=(20.0, 30.0))  # a second head 2 cm deeper
    range_m, amp = (np.where(second.mask, a, b) for a, b in ((second.range_m, range_m), (second.amplitude, amp)))
    near_only = segment(range_m, amp, SegmentationConfig())
    both = segment(range_m, amp, SegmentationConfig(nearest_component=False))
    assert near_only[72, 88] and not near_only[30, 20]
    assert both[72, 88] and both[30, 20]


def test_head_not_a_nearer_shoulder_is_kept():
    """A head-and-shoulders mesh turned and nodded down: a shoulder is nearer than the nose tip."""
    r = render_face(load_face("lee_perry_smith"), Pose(0.7, yaw_deg=29.0, pitch_deg=-14.0))
    u, v = np.round(r.nose_px).astype(int)
    along_z = SegmentationConfig(plane_iterations=0)  # the head band alone (the face plane is tested below)
    anywhere = segment(r.range_m, r.amplitude, dataclasses.replace(along_z, head_height_m=0.0))
    assert not anywhere[v, u] and np.flatnonzero(anywhere.any(axis=1)).min() > v + 30  # the shoulder won
    for cfg in (along_z, SegmentationConfig()):
        head = segment(r.range_m, r.amplitude, cfg)
        assert head[v, u] and not head[v + 50 :].any()  # the face around the nose, no shoulder


def test_fill_holes_and_component_at():
    ring = np.zeros((7, 7), bool)
    ring[1:6, 1:6] = True
    ring[3, 3] = False
    assert fill_holes(ring)[3, 3] and fill_holes(ring).sum() == 25
    notch = ring.copy()
    notch[0:4, 3] = False  # the hole opens to the border: not a hole
    assert not fill_holes(notch)[3, 3]
    two = np.zeros((5, 9), bool)
    two[1:3, 1:3] = True
    two[1:4, 5:8] = True
    assert component_at(two, 2, 6).sum() == 9 and not component_at(two, 0, 0).any()


def test_all_invalid_gives_empty_mask():
    nan = np.full(INTR.shape, np.nan, np.float32)
    assert not segment(nan, nan, SegmentationConfig()).any()
    assert not segment(np.zeros(INTR.shape), np.ones(INTR.shape), SegmentationConfig()).any()


def test_shape_mismatch_is_named():
    with pytest.raises(ValueError, match="range_m"):
        segment(np.zeros((3, 3)), np.zeros((3, 4)), SegmentationConfig())


def test_config_validation_names_key():
    with pytest.raises(ConfigError, match="segmentation.range_percentile"):
        config_from_dict({"segmentation": {"range_percentile": 101}})
    with pytest.raises(ConfigError, match="segmentation.depth_margin_m"):
        config_from_dict({"segmentation": {"depth_margin_m": 0}})
    with pytest.raises(ConfigError, match="segmentation.median_px"):
        config_from_dict({"segmentation": {"median_px": 4}})
    with pytest.raises(ConfigError, match="segmentation.amplitude_method"):
        config_from_dict({"segmentation": {"amplitude_method": "mean"}})
    with pytest.raises(ConfigError, match="segmentation.head_height_m"):
        config_from_dict({"segmentation": {"head_height_m": -0.1}})
    with pytest.raises(ConfigError, match="detector.border_margin_m"):
        config_from_dict({"detector": {"border_margin_m": -0.01}})


def test_rotation_to_z_is_a_proper_rotation_onto_z():
    for direction in (np.array([0.3, -0.2, 0.9]), np.array([0.0, 0.0, 1.0]), np.array([-0.6, 0.1, 0.5])):
        direction = direction / np.linalg.norm(direction)
        r = rotation_to_z(direction)
        assert np.allclose(r @ direction, [0.0, 0.0, 1.0])
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (20.0, 0.0), (0.0, -15.0), (15.0, 15.0)])
def test_cut_runs_along_the_fitted_face_plane(tilt):
    """A tilted disc with a cap (a face with a nose) in front of a wall: the face frame is the disc's normal,
    and the kept pixels are those within depth_margin_m of the cap's top along it, not along the camera's z."""
    scene = synthetic.capped_disc(INTR, 0.5, *tilt).over(synthetic.tilted_plane(INTR, 1.5, 0.0, 0.0))
    cfg = SegmentationConfig()
    fg = segment_face(scene.range_m, scene.amplitude, cfg)
    view = -synthetic.tilt_normal(*tilt)
    assert np.degrees(np.arccos(np.clip(fg.rotation[2] @ view, -1, 1))) < 1.0
    height = INTR.backproject(scene.range_m) @ view  # metres along the face's viewing direction
    top = float(np.nanmin(height))
    assert fg.mask.any() and np.nanmax(height[fg.mask]) <= top + cfg.depth_margin_m + 0.002
    slab = np.isfinite(height) & (height <= top + cfg.depth_margin_m - 0.002)
    assert (fg.mask & slab).sum() >= 0.97 * slab.sum()
    camera_z = segment_face(scene.range_m, scene.amplitude, dataclasses.replace(cfg, plane_iterations=0))
    assert np.array_equal(camera_z.rotation, np.eye(3))
    if tilt != (0.0, 0.0):  # the cut along z is another slab: a tilted face's near edge, not its nose
        assert (camera_z.mask ^ fg.mask).sum() > 0.2 * fg.mask.sum()


@pytest.mark.parametrize(("mode", "frames"), [("WFOV_2X2BINNED", 30), ("WFOV_UNBINNED", 20), ("realsense87", 30)])
@pytest.mark.parametrize("off_axis_deg", [20.0, 40.0])
def test_the_near_sphere_is_the_foreground_on_wide_fields_of_view(mode, frames, off_axis_deg):
    """A sphere 20 (and 40) degrees off axis at 0.85-0.95 m before a wall at 1.6 m, through the Azure Kinect's wide
    lenses (their dark corners outside the lens included) and an 87-degree RealSense-like lens: in every frame the
    foreground is on the sphere and nowhere else."""
    if mode == "realsense87":
        intrinsics, lens_valid = realsense_like_87deg(), None
    else:
        from tofd.drivers.k4a.lens import depth_lens
        from tofd_testing.k4a_helpers import CALIBRATION_JSON

        lens = depth_lens(CALIBRATION_JSON.read_bytes(), mode)
        intrinsics, lens_valid = lens.intrinsics, lens.valid_pixels()
    for k, distance in enumerate(np.linspace(0.85, 0.95, frames)):
        scene = sphere_before_wall(intrinsics, float(distance), 90.0 * (k % 4) + 45.0 * (k % 2), lens_valid,
                                   off_axis_deg)
        mask = segment(scene.range_m, scene.amplitude, SegmentationConfig(), intrinsics)
        assert mask.sum() > 0.2 * scene.sphere.sum() and not (mask & ~scene.sphere).any(), (mode, k, distance)


@pytest.mark.parametrize("radius_m", [0.04, 0.06])
def test_a_small_near_sphere_before_a_lit_wall_is_the_foreground(radius_m):
    """WFOV_2X2BINNED: a ball of 4 or 6 cm radius at 0.85-0.95 m, under 1% of the pixels above the amplitude
    threshold (the wall's bright centre passes it too), is still the nearest object and the only foreground."""
    from tofd.drivers.k4a.lens import depth_lens
    from tofd_testing.k4a_helpers import CALIBRATION_JSON

    lens = depth_lens(CALIBRATION_JSON.read_bytes(), "WFOV_2X2BINNED")
    for k, distance in enumerate(np.linspace(0.85, 0.95, 12)):
        scene = sphere_before_wall(lens.intrinsics, float(distance), 45.0 * k, lens.valid_pixels(), radius_m=radius_m)
        mask = segment(scene.range_m, scene.amplitude, SegmentationConfig(), lens.intrinsics)
        assert mask.sum() > 0.2 * scene.sphere.sum() and not (mask & ~scene.sphere).any(), (radius_m, k)
