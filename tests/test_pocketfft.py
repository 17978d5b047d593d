"""tofd.algorithm.features.pocketfft calls scipy's private pocketfft engine with positional flags: these tests pin
each wrapper's meaning against numpy.fft (a different FFT implementation), in single and double precision, so a
scipy release that changes the engine's signature or flags fails here."""

import numpy as np
import pytest

from tofd.algorithm.features import pocketfft

RNG = np.random.default_rng(37)
PRECISION = {np.complex64: 2e-5, np.complex128: 1e-12}  # relative to the largest value


def close(a: np.ndarray, b: np.ndarray, dtype) -> None:
    np.testing.assert_allclose(a, b, rtol=0, atol=PRECISION[dtype] * np.abs(b).max())


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
@pytest.mark.parametrize("forward", [True, False])
def test_c2c_is_the_unnormalised_fft_along_the_axes_into_out(dtype, forward):
    data = (RNG.standard_normal((3, 10, 6)) + 1j * RNG.standard_normal((3, 10, 6))).astype(dtype)
    out = np.empty_like(data)
    result = pocketfft.c2c(data, axes=(1,), forward=forward, out=out)
    assert result is out
    expected = np.fft.fft(data, axis=1) if forward else np.fft.ifft(data, axis=1) * data.shape[1]
    close(out, expected, dtype)


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_c2r_inverts_a_half_spectrum_to_last_size_points_with_scale_2_dividing_by_n(dtype):
    real = np.float32 if dtype == np.complex64 else np.float64
    field = RNG.standard_normal((8, 8)).astype(real)
    half = np.fft.rfft2(field).astype(dtype)  # (8, 5)
    out = np.empty((8, 8), real)
    assert pocketfft.c2r(half, axes=(0, 1), last_size=8, out=out, scale=2) is out
    close(out, field, dtype)
    unscaled = pocketfft.c2r(half, axes=(0, 1), last_size=8, out=np.empty((8, 8), real))
    close(unscaled, field * 64, dtype)


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_r2c_is_the_forward_half_spectrum_along_the_last_axis(dtype):
    real = np.float32 if dtype == np.complex64 else np.float64
    field = RNG.standard_normal((2, 5, 12)).astype(real)
    out = np.empty((2, 5, 7), dtype)
    assert pocketfft.r2c(field, axes=(2,), out=out) is out
    close(out, np.fft.rfft(field, axis=2), dtype)
