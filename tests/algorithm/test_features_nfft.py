import dataclasses

import numpy as np
import pytest

from tofd.algorithm.features import FFTFeatures, NFFTFeatures
from tofd.algorithm.features.transfer import transfer_functions
from tofd.config import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic

INTR = Intrinsics()
CFG = FeatureConfig()


def _reference_points(range_m, mask, cfg, intr=INTR):
    """Paper section 2.2 steps 1-2, written independently of the implementation."""
    pts = intr.backproject(range_m)[mask]
    lx, ly = cfg.patch_width_m, cfg.patch_height_m
    x, y = pts[:, 0] / lx, pts[:, 1] / ly
    x, y = x - x.mean(), y - y.mean()
    keep = (x < 0.5) & (x >= -0.5) & (y >= -0.5) & (y < 0.5)
    z = pts[keep, 2]
    return x[keep], y[keep], z - z.max(), keep


WIDE = Intrinsics(320, 240, 228.5, 228.5, 159.5, 119.5)  # 70 degrees across: another camera, the same metric patch


@pytest.mark.parametrize("intr, distance", [(INTR, 0.45), (INTR, 0.7), (WIDE, 0.45)])
def test_nfft_matches_dense_ndft_solution(intr, distance):
    """Small grid (a band it holds), tight CG: eps0/eps2 equal those of the exactly solved damped problem (dense
    NDFT)."""
    cfg = dataclasses.replace(CFG, grid_size=16, tuning_frequency_per_m=7.0, lowpass_sigma_per_m=12.0,
                              cg_tolerance=1e-13, cg_max_iterations=5000, nufft_eps=1e-12, cg_precision="double")
    nf = NFFTFeatures(intr, cfg)
    scene = synthetic.sphere(intr, distance, 0.08, apex_px=(intr.cx - 17.5, intr.cy + 8.5))  # (70, 80) on the SR3000
    mask = scene.mask
    maps, amp_maps = nf.features(scene.range_m, mask, amplitude=scene.amplitude)
    x, y, z, keep = _reference_points(scene.range_m, mask, cfg, intr)
    pts = nf.unit_square_points(scene.range_m, mask)
    np.testing.assert_allclose(pts.z, z, atol=1e-12)
    h = cfg.grid_size // 2
    k = np.arange(-h + 1, h)
    kx, ky = (g.ravel() for g in np.meshgrid(k, k))
    a = np.exp(2j * np.pi * (np.outer(x, kx) + np.outer(y, ky)))
    footprint = np.mean(intr.backproject(scene.range_m)[mask][keep, 2] ** 2) / (
        intr.fx * intr.fy * cfg.patch_width_m * cfg.patch_height_m)
    lam = cfg.damping / footprint
    amp = scene.amplitude[mask][keep]
    amp = (amp - amp.min()) / np.median(amp)  # the amplitude surface: FFT path's normalisation, background 0
    lx, ly = cfg.patch_width_m, cfg.patch_height_m
    for values, got in ((z, maps), (amp, amp_maps)):
        coeffs = np.linalg.solve(a.conj().T @ a + lam * np.eye(k.size**2), a.conj().T @ values)
        c0, c2, s2 = (a @ (t * coeffs) for t in transfer_functions(kx / lx, ky / ly, cfg.tuning_frequency_per_m,
                                                                        cfg.lowpass_sigma_per_m))
        eps0_ref, eps2_ref = np.abs(c0) ** 2, np.abs(c2) ** 2 + np.abs(s2) ** 2
        eps0 = got.eps0[mask][keep]
        eps2 = got.eps2[mask][keep]
        assert np.max(np.abs(eps0 - eps0_ref)) <= 1e-4 * np.max(eps0_ref)
        assert np.median(np.abs(eps0 - eps0_ref) / eps0_ref) <= 1e-4
        assert np.max(np.abs(eps2 - eps2_ref)) <= 1e-4 * np.max(eps2_ref)
        assert got.residual <= 1e-12


@pytest.mark.parametrize("distance", [0.35, 0.7])
def test_single_precision_cg_matches_double(distance):
    """The default single-precision CG gives the double-precision features to 1e-4 of their peak."""
    scene = synthetic.sphere(INTR, distance, 0.08, apex_px=(70.0, 80.0))
    maps = {p: NFFTFeatures(INTR, dataclasses.replace(CFG, cg_precision=p)).range_features(scene.range_m, scene.mask)
            for p in ("single", "double")}
    for name in ("eps0", "eps2"):
        single, double = getattr(maps["single"], name), getattr(maps["double"], name)
        assert np.array_equal(np.isfinite(single), np.isfinite(double))
        assert np.nanmax(np.abs(single - double)) <= 1e-4 * np.nanmax(double)
    assert abs(maps["single"].iterations - maps["double"].iterations) <= 2


@pytest.mark.parametrize("turned", [False, True])
def test_points_with_holes_and_rotation_match_the_reference(turned):
    """unit_square_points on a frame with holes (NaN, inf, 0, negative ranges) in the mask and a face-frame
    rotation: the kept pixels, x, y, z, damping and RMS range equal an independent numpy back-projection's."""
    nf = NFFTFeatures(INTR, CFG)
    p = synthetic.tilted_plane(INTR, 0.8, 20.0, -10.0)  # wider than the patch: some points fall outside
    range_m = p.range_m.astype(np.float32)
    holes = np.flatnonzero(p.mask)[::53]
    range_m.reshape(-1)[holes] = np.resize([np.nan, np.inf, 0.0, -1.0], holes.size)
    c, s = np.cos(0.3), np.sin(0.3)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) if turned else None
    pts = nf.unit_square_points(range_m, p.mask, rotation)
    flat = np.flatnonzero(p.mask & np.isfinite(range_m) & (range_m > 0))
    xyz = INTR.unit_rays().reshape(-1, 3)[flat] * range_m.reshape(-1)[flat, None].astype(np.float64)
    if turned:
        xyz = xyz @ rotation.T
    x, y = xyz[:, 0] / CFG.patch_width_m, xyz[:, 1] / CFG.patch_height_m
    x, y = x - x.mean(), y - y.mean()
    keep = (x >= -0.5) & (x < 0.5) & (y >= -0.5) & (y < 0.5)
    assert 0 < keep.sum() < keep.size
    np.testing.assert_array_equal(pts.index, flat[keep])
    z = xyz[keep, 2]
    for got, want in ((pts.x, x[keep]), (pts.y, y[keep]), (pts.z, z - z.max())):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    footprint = np.mean(z**2) / (INTR.fx * INTR.fy * CFG.patch_width_m * CFG.patch_height_m)
    assert pts.damping == pytest.approx(CFG.damping / footprint, rel=1e-12)
    rms = np.sqrt(np.mean(range_m.reshape(-1)[flat[keep]].astype(np.float64) ** 2))
    assert pts.rms_range_m == pytest.approx(rms, rel=1e-12)


def test_points_outside_the_square_are_dropped_and_nan():
    """A wide plane: points beyond +-1/2 after centring get NaN features, the rest finite."""
    nf = NFFTFeatures(INTR, CFG)
    p = synthetic.tilted_plane(INTR, 0.9, 0.0, 0.0)  # field of view at 0.9 m: 1.8 x the patch
    mask = p.mask
    pts = nf.unit_square_points(p.range_m, mask)
    assert 0 < pts.index.size < mask.sum()
    maps = nf.range_features(p.range_m, mask)
    assert np.isfinite(maps.eps0.reshape(-1)[pts.index]).all()
    assert np.count_nonzero(np.isfinite(maps.eps0)) == pts.index.size
    assert pts.x.min() >= -0.5 and pts.x.max() < 0.5


@pytest.mark.parametrize("distance", [0.5, 0.8])
@pytest.mark.parametrize("tilt", [(0.0, 0.0), (30.0, 0.0), (0.0, 45.0), (60.0, 20.0), (-50.0, -30.0)])
def test_plane_at_any_tilt_gives_zero_away_from_border(distance, tilt):
    """eps0, eps2 <= 1 % of the eps0 at a 0.15 m sphere's apex, 6 cm (5 filter widths) inside the border."""
    nf = NFFTFeatures(INTR, CFG)
    sphere = synthetic.sphere(INTR, distance, 0.15)
    reference = nf.range_features(sphere.range_m, sphere.mask).eps0[72, 88]
    p = synthetic.tilted_plane(INTR, distance, *tilt)
    pts = INTR.backproject(p.range_m)
    lateral = np.hypot(pts[..., 0], pts[..., 1])
    maps = nf.range_features(p.range_m, lateral < 0.12)
    inner = lateral < 0.06
    assert np.nanmax(maps.eps0[inner]) <= 0.01 * reference
    assert np.nanmax(maps.eps2[inner]) <= 0.01 * reference


def test_amplitude_features_follow_the_object_not_the_pixel_grid():
    """A 5 cm sphere's Lambertian amplitude at 0.35-0.7 m: the NFFT amplitude eps0 at the apex varies 1.65-fold
    (what is left is the amplitude's own perspective: cos(incidence) and 1/r^2 over the sphere's depth), the
    FFT one 10.8-fold (measured), like the range features' FFT/NFFT contrast."""
    nf, fft = NFFTFeatures(INTR, CFG), FFTFeatures(INTR, CFG)
    nfft_apex, fft_apex = [], []
    for distance in (0.35, 0.5, 0.7):
        s = synthetic.sphere(INTR, distance, 0.05)
        _, amp = nf.features(s.range_m, s.mask, amplitude=s.amplitude)
        nfft_apex.append(amp.eps0[72, 88])
        fft_apex.append(fft.amplitude_features(s.amplitude, s.mask).eps0[72, 88])
    assert max(nfft_apex) / min(nfft_apex) < 2.0
    assert max(fft_apex) / min(fft_apex) > 8.0
    _, scaled = nf.features(s.range_m, s.mask, amplitude=7.0 * s.amplitude)  # gain-free: median normalisation
    np.testing.assert_allclose(scaled.eps0[72, 88], nfft_apex[-1], rtol=1e-4)


def test_iterations_and_residual_reported():
    nf = NFFTFeatures(INTR, CFG)
    s = synthetic.sphere(INTR, 0.5, 0.15)
    maps = nf.range_features(s.range_m, s.mask)
    assert 1 <= maps.iterations <= CFG.cg_max_iterations
    assert maps.residual <= CFG.cg_tolerance
    capped = NFFTFeatures(INTR, dataclasses.replace(CFG, cg_max_iterations=2)).range_features(s.range_m, s.mask)
    assert capped.iterations == 2 and capped.residual > CFG.cg_tolerance


def test_empty_mask():
    nf = NFFTFeatures(INTR, CFG)
    maps = nf.range_features(np.ones(INTR.shape), np.zeros(INTR.shape, bool))
    assert np.all(np.isnan(maps.eps0)) and maps.iterations == 0


@pytest.mark.parametrize("tilt", [(20.0, 0.0), (0.0, -15.0), (15.0, 15.0)])
def test_face_frame_makes_a_tilted_face_look_frontal(tilt):
    """A disc with a spherical cap, tilted: with the segmentation's face frame the NFFT features at the cap's
    top equal those of the frontal disc (eps2 ~ 0 by symmetry); in the camera frame the tilt shears the
    height field (eps2 > 0, eps0 off)."""
    from tofd.algorithm.segmentation import segment_face
    from tofd.config import SegmentationConfig

    nfft = NFFTFeatures(INTR, CFG)
    wall = synthetic.tilted_plane(INTR, 1.5, 0.0, 0.0)

    def top_features(t, frame):
        scene = synthetic.capped_disc(INTR, 0.5, *t).over(wall)
        fg = segment_face(scene.range_m, scene.amplitude, SegmentationConfig(), INTR)
        maps = nfft.range_features(scene.range_m, fg.mask, fg.rotation if frame else None)
        height = INTR.backproject(scene.range_m) @ -synthetic.tilt_normal(*t)
        top = np.unravel_index(np.nanargmin(np.where(fg.mask, height, np.nan)), height.shape)
        return maps.eps0[top], maps.eps2[top]

    frontal0, frontal2 = top_features((0.0, 0.0), True)
    assert frontal2 < 1e-4 * frontal0
    eps0, eps2 = top_features(tilt, True)
    assert eps0 == pytest.approx(frontal0, rel=0.02) and eps2 < 1e-4 * eps0
    cam0, cam2 = top_features(tilt, False)
    assert abs(cam0 / frontal0 - 1) > 0.1 and cam2 > 5e-4 * cam0
