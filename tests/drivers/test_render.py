"""The renderer against analytic geometry: a fronto-parallel square and a tilted plane."""

import numpy as np
import pytest

from tofd.drivers.emulator.render import FACE_NAMES, FaceMesh, Pose, SensorModel, load_face, rasterize, render_face
from tofd.drivers.intrinsics import Intrinsics

INTR = Intrinsics()


def square(half_m: float, z_m: float, tilt_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A square of side 2*half_m centred on the optical axis at depth z_m, tilted about the y axis."""
    t = np.radians(tilt_deg)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * half_m
    verts = np.column_stack([corners[:, 0] * np.cos(t), corners[:, 1], z_m + corners[:, 0] * np.sin(t)])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("tilt", [0.0, 35.0])
def test_plane_range_is_exact_ray_intersection(tilt):
    verts, faces = square(0.1, 0.5, tilt)
    range_m, cosine = rasterize(verts, faces, INTR)
    hit = np.isfinite(range_m)
    rays = INTR.unit_rays()
    normal = np.array([-np.sin(np.radians(tilt)), 0.0, np.cos(np.radians(tilt))])
    expected = 0.5 * normal[2] / (rays @ normal)
    np.testing.assert_allclose(range_m[hit], expected[hit], rtol=1e-9)
    np.testing.assert_allclose(cosine[hit], np.abs(rays @ normal)[hit], rtol=1e-9)
    # the square covers the pixels whose centre projects inside it: about (2 * 0.1 / 0.5 * f)^2 for no tilt
    if tilt == 0.0:
        side_px = 2 * 0.1 / 0.5 * INTR.fx
        assert abs(hit.sum() - side_px**2) < 4 * side_px


def test_nearest_surface_wins():
    near, faces = square(0.05, 0.4)
    far, _ = square(0.1, 0.6)
    range_m, _ = rasterize(np.vstack([far, near]), np.vstack([faces, faces + 4]), INTR)
    centre = range_m[int(INTR.cy), int(INTR.cx)]
    assert centre == pytest.approx(0.4 / INTR.unit_rays()[int(INTR.cy), int(INTR.cx), 2], rel=1e-9)
    assert np.nanmin(range_m) < 0.401 and np.nanmax(range_m) > 0.6


@pytest.mark.parametrize("name", FACE_NAMES)
@pytest.mark.parametrize("distance", [0.35, 0.7])
def test_face_nose_ground_truth(name, distance):
    mesh = load_face(name)
    r = render_face(mesh, Pose(distance, yaw_deg=15, pitch_deg=-10, nose_px=(80.0, 70.0)))
    assert r.nose_visible
    assert r.nose_px == pytest.approx((80.0, 70.0), abs=1e-6)
    assert np.linalg.norm(r.nose_xyz_m) == pytest.approx(distance, abs=1e-9)
    # the nose tip is the nearest point of a frontal face, and it is on the face mask
    assert r.face_mask[70, 80]
    assert r.range_m[70, 80] == pytest.approx(distance, abs=0.01)


def test_amplitude_falls_with_range_squared_and_noise_grows():
    mesh = load_face("mediapipe_canonical")
    near = render_face(mesh, Pose(0.35))
    far = render_face(mesh, Pose(0.7))
    ratio = near.amplitude[int(INTR.cy), int(INTR.cx)] / far.amplitude[int(INTR.cy), int(INTR.cx)]
    assert ratio == pytest.approx(4.0, rel=0.05)
    rng = np.random.default_rng(0)
    model = SensorModel(flying_pixel_fraction=0.0)
    noisy = [render_face(mesh, Pose(d), rng=rng, model=model) for d in (0.35, 0.7)]
    clean = [near, far]
    # range noise ~ 1/amplitude ~ range^2: four times larger at twice the distance (median absolute error)
    err = [np.median(np.abs(n.range_m - c.range_m)[c.face_mask]) for n, c in zip(noisy, clean, strict=True)]
    assert err[1] / err[0] == pytest.approx(4.0, rel=0.25)


def test_flying_pixels_only_on_depth_edges():
    mesh = load_face("mediapipe_canonical")
    clean = render_face(mesh, Pose(0.5))
    noisy = render_face(mesh, Pose(0.5), rng=np.random.default_rng(1),
                        model=SensorModel(range_noise_m=0.0, max_range_noise_m=0.0, amplitude_noise=0.0))
    changed = np.abs(noisy.range_m - clean.range_m) > 1e-4
    assert changed.sum() > 50
    # every changed pixel lies between the face and the wall: a mix, never outside that range
    assert np.all(noisy.range_m[changed] > clean.range_m[changed])
    assert np.all(noisy.range_m[changed] < 1.7 / INTR.unit_rays()[..., 2][changed])


def test_unknown_face_is_named():
    with pytest.raises(ValueError, match="nobody"):
        load_face("nobody")


def test_with_vertices_keeps_topology():
    mesh = load_face("mediapipe_canonical")
    bigger = mesh.with_vertices(mesh.vertices * 1.1, name="big")
    assert isinstance(bigger, FaceMesh) and bigger.faces is mesh.faces and bigger.name == "big"


def test_smooth_shading_follows_the_true_normal_of_a_tessellated_sphere():
    """Interpolated vertex normals give a sphere's analytic incidence angle far better than its facets do."""
    theta, phi = np.meshgrid(np.linspace(0, np.pi, 25), np.linspace(0, 2 * np.pi, 49, endpoint=False), indexing="ij")
    unit = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(24), np.arange(49), indexing="ij")
    a, b = i * 49 + j, i * 49 + (j + 1) % 49
    faces = np.concatenate([np.stack([a, b, a + 49], -1), np.stack([b, b + 49, a + 49], -1)]).reshape(-1, 3)
    centre = np.array([0.0, 0.0, 0.6])
    range_m, cosine = rasterize(centre + 0.1 * unit, faces, INTR)
    hit = np.isfinite(range_m)
    points = INTR.backproject(np.where(hit, range_m, 0.0))
    normal = (points - centre) / np.linalg.norm(points - centre, axis=-1, keepdims=True)
    analytic = np.abs(np.einsum("hwk,hwk->hw", normal, INTR.unit_rays()))
    centre_region = hit & (analytic > 0.5)
    assert np.percentile(np.abs(cosine - analytic)[centre_region], 95) < 0.01


def test_constant_noise_model_is_the_same_at_every_distance():
    mesh = load_face("mediapipe_canonical")
    rng = np.random.default_rng(2)
    model = SensorModel(flying_pixel_fraction=0.0, noise_model="constant", range_noise_m=0.003)
    err = []
    for d in (0.35, 0.7):
        clean = render_face(mesh, Pose(d))
        noisy = render_face(mesh, Pose(d), rng=rng, model=model)
        err.append(np.std((noisy.range_m - clean.range_m)[clean.face_mask]))
    assert err == pytest.approx([0.003, 0.003], rel=0.1)


def test_no_wall_leaves_the_background_without_a_return():
    mesh = load_face("mediapipe_canonical")
    r = render_face(mesh, Pose(0.5), rng=np.random.default_rng(3), model=SensorModel(wall_distance_m=None))
    assert np.all(np.isnan(r.range_m[~r.face_mask]))
    assert np.all(r.amplitude[~r.face_mask] == 0)
    assert np.isfinite(r.range_m[r.face_mask]).mean() > 0.99
