"""The NFFT path's reused plans and buffers and its compiled glue: nothing carries over from one frame (or one number
of surfaces) to the next, and the half spectrum is expanded as Hermitian symmetry says."""

import finufft
import numpy as np
import pytest

from tofd.algorithm.features import NFFTFeatures
from tofd.algorithm.features.normal_equations import DampedNormalEquations, norm_weights, solve
from tofd.algorithm.features.spectra_kernels import hermitian_full
from tofd.config import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import shapes as synthetic

INTR = Intrinsics()


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_hermitian_full_rebuilds_a_real_fields_spectrum(dtype):
    """From the compact half (rows ky = 0 .. N/2 - 1, -N/2 + 1 .. -1; columns kx = 0 .. N/2 - 1) of a real field's
    FFT, the whole FFT-ordered spectrum, with the unpaired Nyquist row and column 0."""
    n, h = 16, 8
    spectrum = np.fft.fft2(np.random.default_rng(1).standard_normal((n, n)))
    half = np.concatenate((spectrum[:h, :h], spectrum[n - h + 1:, :h])).astype(dtype)
    out = np.full((n, n), np.nan, dtype)
    hermitian_full(half, out)
    want = spectrum.copy()
    want[h, :] = want[:, h] = 0
    np.testing.assert_allclose(out, want, rtol=1e-6, atol=1e-5 * np.abs(want).max())


def _kernel(n: int) -> np.ndarray:
    rng = np.random.default_rng(n)
    x, y = rng.uniform(-0.4, 0.4, 200), rng.uniform(-0.4, 0.4, 200)
    return finufft.nufft2d1(2 * np.pi * y, 2 * np.pi * x, np.ones(x.size, complex), (2 * n, 2 * n), eps=1e-13,
                            modeord=1, isign=-1)


def test_a_zero_right_hand_side_leaves_the_batch_at_once():
    """A zero rhs beside a non-zero one: 0 iterations, residual 0, f = 0; the other solves as it would alone."""
    n, h = 8, 4
    system = DampedNormalEquations(n, np.float64, np.complex128).set_kernel(_kernel(n), 2.5)
    b = np.fft.fft2(np.random.default_rng(2).standard_normal((n, n)))
    b = np.concatenate((b[:h, :h], b[n - h + 1:, :h]))
    weights = norm_weights(np.ones(b.shape))
    zero, other = solve(system, np.stack((np.zeros_like(b), b)), weights, 1e-10, 500)
    alone = solve(system, b[None], weights, 1e-10, 500)[0]
    assert zero.iterations == 0 and zero.residual == 0.0 and not np.any(zero.f)
    assert other.iterations == alone.iterations > 0
    np.testing.assert_allclose(other.f, alone.f, rtol=1e-9, atol=1e-12 * np.abs(alone.f).max())


def test_a_reused_instance_gives_what_a_fresh_one_gives():
    """Frames of different sizes, with and without the amplitude surface, through one instance (its plans, solver
    and grids reused): each frame's maps equal those of a new instance."""
    cfg = FeatureConfig()
    frames = []
    for distance, radius in ((0.4, 0.12), (0.65, 0.06), (0.5, 0.09)):
        s = synthetic.sphere(INTR, distance, radius)
        frames.append((s.range_m, s.mask, s.amplitude))
    reused = NFFTFeatures(INTR, cfg)
    for range_m, mask, amplitude in frames + frames[::-1]:
        for amp in (None, amplitude):
            got = reused.features(range_m, mask, amplitude=amp)
            want = NFFTFeatures(INTR, cfg).features(range_m, mask, amplitude=amp)
            for g, w in zip(got, want, strict=True):
                if w is None:
                    assert g is None
                    continue
                assert g.iterations == w.iterations
                for a, b in ((g.eps0, w.eps0), (g.eps2, w.eps2)):
                    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9 * np.nanmax(b), equal_nan=True)


@pytest.mark.parametrize("precision", ["single", "double"])
def test_frames_compile_nothing_after_construction(precision):
    """The compiled loops are loaded for the frames' argument types when the instance is made: frames (with and
    without the amplitude surface) add no numba specialisation, so a live run's first frame does not wait for one."""
    from tofd.algorithm.features.compiled import compiled

    nf = NFFTFeatures(INTR, FeatureConfig(cg_precision=precision))
    loops = [getattr(compiled(module), name) for module, names in (
        ("spectra_kernels", ("pack_pairs", "separate_pairs", "hermitian_full")), ("cg_kernels", ("cg_step", "norms")),
        ("patch_points", ("patch_points",))) for name in names]
    before = [len(loop.signatures) for loop in loops]
    s = synthetic.sphere(INTR, 0.5, 0.1)
    nf.features(s.range_m, s.mask)
    nf.features(s.range_m, s.mask, amplitude=s.amplitude)
    assert [len(loop.signatures) for loop in loops] == before
