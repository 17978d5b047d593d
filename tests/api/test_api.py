"""The public API (tofd.*) on arrays built here: analytic spheres by ray-sphere intersection, quantised depth."""

import ast
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import tofd
from tofd.lab import shapes

R = 0.1  # sphere radius, metres


def camera(width: int, height: int, *, fov_deg: float | None = None, f: float | None = None) -> tofd.Intrinsics:
    if f is None:
        f = (width / 2) / math.tan(math.radians(fov_deg / 2))
    return tofd.Intrinsics(width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2)


CAMERAS = {"176x144": tofd.Intrinsics(), "320x240": camera(320, 240, fov_deg=70.0),
           "640x576": camera(640, 576, f=504.0)}


def apex(intr: tofd.Intrinsics) -> tuple[int, int]:
    return int(round(intr.cy)), int(round(intr.cx))


def sphere_range(intr: tofd.Intrinsics, distance: float) -> np.ndarray:
    return shapes.sphere(intr, distance, R).range_m


def laplacian_of_gaussian(sigma_per_m: float):
    """The Laplacian (2 pi i k)^2 = -(2 pi)^2 |k|^2 times a Gaussian of width sigma_per_m cycles per metre."""
    def transfer(kx, ky):
        k2 = kx**2 + ky**2
        return -(2 * np.pi) ** 2 * k2 * np.exp(-k2 / (2 * sigma_per_m**2))
    return transfer


def test_public_names_are_exported_typed_and_documented():
    assert {"Intrinsics", "FeatureConfig", "eccentricities", "surface_filter", "range_from_depth", "detect_nose",
            "train_model", "evaluate_model", "eccentricity_transfer"} <= set(tofd.__all__)
    source = Path(tofd.__file__).read_text()
    checked = {alias.asname for node in ast.walk(ast.parse(source)) if isinstance(node, ast.If)
               for stmt in node.body if isinstance(stmt, ast.ImportFrom) for alias in stmt.names}
    assert checked == set(tofd.__all__) - {"__version__"}  # the type checkers' names are the runtime ones
    for name in tofd.__all__:
        value = getattr(tofd, name)
        assert name == "__version__" or value.__doc__, name
    for fn in (tofd.eccentricities, tofd.surface_filter, tofd.range_from_depth, tofd.detect_nose):
        assert "Parameters" in fn.__doc__ and "Returns" in fn.__doc__
    assert (Path(tofd.__file__).parent / "py.typed").exists()
    with pytest.raises(AttributeError):
        tofd.no_such_name  # noqa: B018


def test_import_tofd_loads_no_service_libraries():
    code = ("import sys, tofd; tofd.eccentricities, tofd.surface_filter, tofd.detect_nose; "
            "print(','.join(m for m in ('rerun', 'dask', 'distributed', 'usb', 'mcap', 'rosbags', "
            "'prometheus_client') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_nfft_eps0_at_a_sphere_apex_is_the_same_for_every_camera_and_distance():
    values = {(name, d): tofd.eccentricities(sphere_range(intr, d), intr).eps0[apex(intr)]
              for name, intr in CAMERAS.items() for d in (0.35, 0.8)}
    ref = values["176x144", 0.35]
    assert ref > 0
    for key, value in values.items():
        assert value == pytest.approx(ref, rel=0.03), key


@pytest.mark.parametrize("method", ["nfft", "fft"])
def test_nan_holes_inside_the_mask_leave_the_rest_of_the_frame_alone(method):
    intr = CAMERAS["320x240"]
    r = sphere_range(intr, 0.5)
    mask = np.isfinite(r)
    clean = tofd.eccentricities(r, intr, mask=mask, method=method)
    rows, cols = np.nonzero(mask & (np.hypot(*np.indices(r.shape) - np.array(apex(intr))[:, None, None]) > 6))
    pick = np.random.default_rng(0).choice(rows.size, 20, replace=False)
    holed = r.copy()
    holed[rows[pick], cols[pick]] = [np.nan, np.inf, -np.inf, 0.0, -1.0] * 4
    got = tofd.eccentricities(holed, intr, mask=mask, method=method)
    hole = np.zeros_like(mask)
    hole[rows[pick], cols[pick]] = True
    assert np.isnan(got.eps0[hole]).all() and np.isnan(got.eps2[hole]).all()
    assert np.isfinite(got.eps0[mask & ~hole]).all() and np.isfinite(got.eps2[mask & ~hole]).all()
    assert got.eps0[apex(intr)] == pytest.approx(clean.eps0[apex(intr)], rel=0.03)


def test_range_in_millimetres_is_refused():
    intr = CAMERAS["176x144"]
    r = sphere_range(intr, 0.5)
    for method in ("nfft", "fft"):
        with pytest.raises(ValueError, match="range_m looks like millimetres"):
            tofd.eccentricities(1000.0 * r, intr, method=method)
    with pytest.raises(ValueError, match="range_m must be a floating-point array.*range_from_depth"):
        tofd.eccentricities(np.nan_to_num(1000 * r).astype(np.uint16), intr)


@pytest.mark.parametrize("distance", [0.35, 0.5, 0.8])
def test_a_laplacian_of_gaussian_through_surface_filter_gives_2_over_r_at_the_apex(distance):
    for intr in CAMERAS.values():
        field = tofd.surface_filter(sphere_range(intr, distance), intr, laplacian_of_gaussian(20.0))
        assert field.shape == intr.shape and field.dtype == np.float64
        assert field[apex(intr)] == pytest.approx(2 / R, rel=0.10)


def test_eccentricity_transfer_gives_the_eccentricities_and_any_order():
    intr = CAMERAS["176x144"]
    r = sphere_range(intr, 0.5)
    features = tofd.eccentricities(r, intr)
    for method in ("nfft", "fft"):
        ref = tofd.eccentricities(r, intr, method=method)
        for n, want in ((0, ref.eps0), (2, ref.eps2)):
            fields = tofd.surface_filter(r, intr, tofd.eccentricity_transfer(n), method=method)
            assert fields.shape == (2, *intr.shape) and fields.dtype == np.float64  # Hermitian: real fields
            eps = (fields**2).sum(axis=0)
            fin = np.isfinite(want)
            np.testing.assert_allclose(eps[fin], want[fin], rtol=2e-3, atol=1e-3 * np.nanmax(want))
    eps3 = (tofd.surface_filter(r, intr, tofd.eccentricity_transfer(3)) ** 2).sum(axis=0)
    assert eps3[apex(intr)] < 1e-3 * features.eps0[apex(intr)]  # odd orders vanish at a symmetric apex
    assert np.nanmax(eps3) > 1e-2 * np.nanmax(features.eps0)  # ... but not on the flanks


def test_non_hermitian_operators_give_complex_fields_equal_to_their_hermitian_parts():
    """H = LoG * (1 + 0.5 sign(kx)) is not Hermitian (H(-k) != conj H(k)): its field is LoG's plus i/2 times the
    field of the Hermitian -i sign(kx) LoG (a Hilbert transform along x)."""
    intr = CAMERAS["176x144"]
    r = sphere_range(intr, 0.5)
    log = laplacian_of_gaussian(20.0)
    for method in ("nfft", "fft"):
        both = tofd.surface_filter(r, intr, lambda kx, ky: log(kx, ky) * (1 + 0.5 * np.sign(kx)), method=method)
        parts = tofd.surface_filter(r, intr, lambda kx, ky: np.stack([log(kx, ky), -1j * np.sign(kx) * log(kx, ky)]),
                                    method=method)
        assert both.dtype == np.complex128 and parts.dtype == np.float64
        fin = np.isfinite(both)
        assert np.abs(both[fin].imag).max() > 0.05 * np.abs(both[fin].real).max()
        np.testing.assert_allclose(both[fin], (parts[0] + 0.5j * parts[1])[fin], atol=1e-4 * np.nanmax(np.abs(both)))


def test_range_from_depth_is_exact_to_the_depth_step():
    intr = CAMERAS["640x576"]
    true_range = sphere_range(intr, 0.5)
    rays_z = intr.unit_rays()[..., 2]
    depth_mm = np.round(np.nan_to_num(true_range * rays_z) * 1000).astype(np.uint16)  # what a camera gives
    got = tofd.range_from_depth(depth_mm, intr, scale=0.001)
    valid = depth_mm > 0
    assert np.array_equal(np.isfinite(got), valid)
    # half a millimetre of z-rounding is at most 0.5 mm / ray_z of range
    assert np.all(np.abs(got[valid] - true_range[valid]) <= 0.0005 / rays_z[valid] + 1e-12)
    float_depth = np.where(valid, depth_mm * 0.001, np.nan)
    float_depth[0, :3] = [np.inf, -1.0, 0.0]
    metres = tofd.range_from_depth(float_depth, intr, scale=1.0)
    assert np.isnan(metres[0, :3]).all()
    np.testing.assert_allclose(metres[valid], got[valid], rtol=1e-12)
    with pytest.raises(ValueError, match="scale"):
        tofd.range_from_depth(depth_mm, intr, scale=0)


@pytest.mark.parametrize("call, message", [
    (lambda r, i: tofd.eccentricities(r.astype(np.float32)[:-1], i), "range_m has shape"),
    (lambda r, i: tofd.eccentricities(r.tolist(), i), "range_m must be a numpy array"),
    (lambda r, i: tofd.eccentricities(r, i, mask=np.isfinite(r).astype(np.uint8)), "mask must be a bool array"),
    (lambda r, i: tofd.eccentricities(r, i, mask=np.ones((3, 3), bool)), "mask must be a bool array"),
    (lambda r, i: tofd.eccentricities(r, i, method="dft"), "method must be one of"),
    (lambda r, i: tofd.eccentricities(r, i, config={"grid_size": 64}), "config must be a tofd.FeatureConfig"),
    (lambda r, i: tofd.eccentricities(r, (176, 144)), "intrinsics must be a tofd.Intrinsics"),
    (lambda r, i: tofd.surface_filter(r, i, lambda kx, ky: kx[:2]), "transfer must return an array of shape"),
    (lambda r, i: tofd.surface_filter(r, i, lambda kx, ky: np.full_like(kx, np.nan)), "transfer returned non-finite"),
    (lambda r, i: tofd.surface_filter(r, i, 3.0), "transfer must be a callable"),
    (lambda r, i: tofd.eccentricity_transfer(-1), "n must be an integer"),
])
def test_bad_arguments_raise_one_value_error_naming_them(call, message):
    intr = CAMERAS["176x144"]
    with pytest.raises(ValueError, match=message):
        call(sphere_range(intr, 0.5), intr)


def test_mask_none_uses_every_valid_pixel_and_an_empty_mask_gives_nan():
    intr = CAMERAS["176x144"]
    r = sphere_range(intr, 0.5)
    features = tofd.eccentricities(r, intr)
    assert np.array_equal(np.isfinite(features.eps0), np.isfinite(r))
    empty = tofd.eccentricities(r, intr, mask=np.zeros(intr.shape, bool))
    assert np.isnan(empty.eps0).all() and np.isnan(empty.eps2).all()


def test_a_far_object_on_a_coarse_camera_is_refused_not_wrong():
    intr = CAMERAS["176x144"]
    with pytest.raises(tofd.SamplingError, match="too coarse"):
        tofd.eccentricities(sphere_range(intr, 2.0), intr)
