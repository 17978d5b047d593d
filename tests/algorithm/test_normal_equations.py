import dataclasses

import finufft
import numpy as np
import pytest

from tofd.algorithm.features import NFFTFeatures
from tofd.algorithm.features.normal_equations import DampedNormalEquations, hermitian_norms, norm_weights, solve
from tofd.config import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic


def _half_to_full(half: np.ndarray, n: int) -> np.ndarray:
    """Compact half spectrum -> the (N - 1) x (N - 1) modes k in (-N/2, N/2)^2, rows ky, columns kx, centred."""
    h = n // 2
    rows = np.concatenate((half[h:], half[:h]))  # ky = -h + 1 .. h - 1
    full = np.zeros((n - 1, n - 1), complex)
    full[:, h - 1:] = rows
    full[:, : h - 1] = np.conj(rows[::-1, :0:-1])  # f(-ky, -kx) = conj f(ky, kx)
    return full


@pytest.mark.parametrize("n", [8, 16])
def test_operator_equals_dense_damped_normal_matrix(n):
    """A^H A v through the pruned 2N circulant equals the dense NDFT matrix product (the FFTs are ducc0's, called
    with their normalisation and direction flags: this pins their semantics), and CG's Hermitian norms equal the full
    spectrum's."""
    rng = np.random.default_rng(n)
    x, y = rng.uniform(-0.3, 0.4, 300), rng.uniform(-0.45, 0.2, 300)
    kernel = finufft.nufft2d1(2 * np.pi * y, 2 * np.pi * x, np.ones(x.size, complex), (2 * n, 2 * n), eps=1e-13,
                              modeord=1, isign=-1)
    lam = 3.7
    system = DampedNormalEquations(n, np.float64, np.complex128).set_kernel(kernel, lam)
    h = n // 2

    def half_of_real_field() -> np.ndarray:  # a real field's half spectrum is Hermitian in its kx = 0 column
        spec = np.fft.fft2(rng.standard_normal((n, n)))
        return np.concatenate((spec[:h, :h], spec[n - h + 1:, :h]))

    def product(system: DampedNormalEquations, v: np.ndarray) -> np.ndarray:
        embedded = system.embed(v)
        return _half_to_full(system.compact(system.product(embedded, np.empty_like(embedded)))[0], n)

    v = half_of_real_field()[None]
    k = np.arange(-h + 1, h)
    kx, ky = (g.ravel() for g in np.meshgrid(k, k))
    a = np.exp(2j * np.pi * (np.outer(x, kx) + np.outer(y, ky)))
    normal = a.conj().T @ a + lam * np.eye(k.size**2)
    want = ((normal - lam * np.eye(k.size**2)) @ _half_to_full(v[0], n).ravel()).reshape(n - 1, n - 1)
    np.testing.assert_allclose(product(system, v), want, atol=1e-9 * np.abs(want).max())
    # buffers reused: nothing left over
    np.testing.assert_allclose(product(system, 2 * v), 2 * want, atol=2e-9 * np.abs(want).max())
    single = DampedNormalEquations(n, np.float32, np.complex64).set_kernel(kernel, lam)
    for _ in range(2):
        np.testing.assert_allclose(product(single, v.astype(np.complex64)), want, atol=1e-5 * np.abs(want).max())
    full = _half_to_full(v[0], n)
    band = rng.uniform(0, 1, v.shape[1:])
    plain, banded = hermitian_norms(v[0], norm_weights(band))
    assert plain == pytest.approx(np.vdot(full, full).real)
    assert banded == pytest.approx(np.sum(np.abs(_half_to_full(band * v[0], n)) ** 2))

    # two right-hand sides solved together: each equals its dense solution, each stops on its own residual
    rhs = np.stack((v[0], 1e3 * half_of_real_field()))
    weights = norm_weights(np.ones(v.shape[1:]))
    solved = solve(system, rhs, weights, 1e-10, 1000)
    for s, b in zip(solved, rhs, strict=True):
        np.testing.assert_allclose(_half_to_full(s.f, n), np.linalg.solve(normal, _half_to_full(b, n).ravel()).reshape(
            n - 1, n - 1), rtol=1e-8, atol=1e-10 * np.abs(_half_to_full(s.f, n)).max())
        alone = solve(system, b[None], weights, 1e-10, 1000)[0]
        assert s.residual <= 1e-10 and alone.residual <= 1e-10
        np.testing.assert_allclose(s.f, alone.f, rtol=1e-7, atol=1e-9 * np.abs(alone.f).max())


@pytest.mark.parametrize("distance", [0.35, 0.7])
def test_default_stopping_gives_eps0_within_1_percent_of_converged(distance):
    """Default CG (single precision, tolerance 1e-4) against a double-precision solve to 1e-10, on a noisy
    sphere: eps0 within 1 % of the converged peak everywhere, and at its median pixel within 0.2 %."""
    intr, cfg = Intrinsics(), FeatureConfig()
    scene = synthetic.sphere(intr, distance, 0.08)
    noisy = scene.range_m + 0.002 * np.random.default_rng(3).standard_normal(scene.range_m.shape)
    got = NFFTFeatures(intr, cfg).range_features(noisy, scene.mask)
    tight = dataclasses.replace(cfg, cg_tolerance=1e-10, cg_max_iterations=3000, cg_precision="double")
    ref = NFFTFeatures(intr, tight).range_features(noisy, scene.mask)
    fin = np.isfinite(ref.eps0)
    assert np.array_equal(fin, np.isfinite(got.eps0)) and fin.sum() > 1000
    error = np.abs(got.eps0[fin] - ref.eps0[fin])
    assert np.max(error) < 0.01 * np.max(ref.eps0[fin])
    assert np.median(error / ref.eps0[fin]) < 0.002
    assert got.iterations < ref.iterations


def test_real_pair_spectra_equal_direct_sums():
    """Three real strength sets through two packed complex transforms equal their direct sums
    sum_j v_j exp(-i m.x_j) (m in FFT order; not on the unpaired m = -N row and column, whose mirror is off the
    grid), in double precision and for a single-precision plan."""
    from tofd.algorithm.features.nfft import real_pair_spectra

    rng = np.random.default_rng(5)
    n = 6
    x, y = rng.uniform(-np.pi, np.pi, 50), rng.uniform(-np.pi, np.pi, 50)
    rows = np.stack((np.ones(50), 0.01 * rng.standard_normal(50), 1 + rng.random(50)))
    m = np.fft.fftfreq(2 * n, 1.0 / (2 * n))
    direct = np.einsum("vj,yj,xj->vyx", rows, np.exp(-1j * np.outer(m, y)), np.exp(-1j * np.outer(m, x)))
    for dtype, rtol in ((np.complex128, 1e-10), (np.complex64, 1e-4)):
        plan = finufft.Plan(1, (2 * n, 2 * n), n_trans=2, isign=-1, modeord=1, dtype=dtype,
                            eps=1e-12 if dtype == np.complex128 else 1e-5)
        real = np.float64 if dtype == np.complex128 else np.float32
        plan.setpts(y.astype(real), x.astype(real))
        got = real_pair_spectra(plan, rows, n + 1)
        assert got.shape == (3, 2 * n, n + 1)
        paired = np.ones((2 * n, n + 1), bool)
        paired[n, :] = paired[:, n] = False
        for v in range(3):  # each set to the precision of its own scale
            err = np.abs(got[v] - direct[v, :, : n + 1])[paired].max()
            assert err <= rtol * np.abs(rows[v]).sum()
