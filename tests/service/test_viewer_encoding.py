"""What the viewers carry (tofd/service/viewer/encoding.py, pixels.cloud_pixels): depth in the source's own integers
where they are exact, read back from a real Foxglove server by a plain client, lining up with the 3-D cloud."""

from dataclasses import replace

import numpy as np
import pytest

from tofd.algorithm.segmentation import foreground_box
from tofd.config import Config
from tofd.drivers import sr3000
from tofd.drivers.frame import Frame, Registers, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.cameras import CAMERAS
from tofd.service.foxglove import topics as t
from tofd.service.foxglove.publisher import FoxglovePublisher
from tofd.service.foxglove.spec import parse_foxglove_spec
from tofd.service.pipeline.results import FrameResult
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.encoding import (
    AMPLITUDE_SAMPLE_STEP,
    amplitude_u8,
    code_unit_m,
    in_units,
    jpeg,
    png,
    scaled_u8,
    scaled_u16,
    units_per_range_m,
    unpng,
    z_depth_m,
)
from tofd.service.viewer.pixels import CLOUD_POINTS, cloud_pixels
from tofd_testing.foxglove_client import Client

K4A = CAMERAS["k4a-nfov"]


def millimetre_frame(counter: int) -> tuple[Frame, np.ndarray]:
    """A 640x576 frame as the Azure Kinect driver delivers a slanted wall in whole millimetres of z-depth (radial
    range = mm * 1e-3 / ray z, in float32), and those millimetres (0: no return)."""
    v, u = np.indices(K4A.shape)
    z_mm = (650 + u // 2 + v // 3 + counter).astype(np.uint16)
    z_mm[:16, :24] = 0
    scale = np.float32(1e-3) / K4A.unit_rays()[..., 2].astype(np.float32)
    radial = np.where(z_mm > 0, z_mm * scale, np.nan).astype(np.float32)
    frame = Frame(radial, (200 + (u + v) % 900).astype(np.float32), counter, counter * 33_333, 0.0, 0.0,
                  intrinsics=K4A, sensor=SensorInfo(depth_unit_m=1e-3, amplitude="ir"))
    return frame, z_mm


def test_whole_units_are_recognised_and_round_trip_through_png():
    frame, z_mm = millimetre_frame(0)
    units, exact = in_units(z_depth_m(frame.range_m, K4A.unit_rays()[..., 2].astype(np.float32)), 1e-3)
    assert exact and np.array_equal(units, z_mm)
    assert np.array_equal(unpng(png(units)), z_mm)  # lossless, uint16
    # the SR3000's radial codes are whole units of c / (2 f) / 65535 (not as z-depth)
    registers = Registers()
    raw = np.random.default_rng(0).integers(1000, 60000, (144, 176)).astype(np.uint16)
    radial = sr3000.raw_to_range_m(raw, sr3000.mod_freq_khz(registers.mod_freq_index))
    sr = Frame(radial, np.ones_like(radial), 0, 0, 0.0, 0.0, registers=registers)
    codes, exact = in_units(radial, code_unit_m(sr))
    assert exact and np.array_equal(codes, raw)
    assert not in_units(z_depth_m(radial, Intrinsics().unit_rays()[..., 2].astype(np.float32)), code_unit_m(sr))[1]
    assert not in_units(np.float32([[0.5004]]), 1e-3)[1]  # not a whole millimetre


def test_one_pass_scaling_rounds_and_saturates_as_numpy_does():
    """scaled_u16 / scaled_u8 (OpenCV's saturating multiply) against numpy's rint, clip and cast: ties to even, NaN
    and negatives 0, the top saturates, infinities 0; per pixel factors too; and a millimetre camera's radial
    range goes to its whole millimetres of z-depth in one pass."""
    rng = np.random.default_rng(11)
    plane = rng.uniform(-50, 70000, (61, 83)).astype(np.float32)
    plane[::7, ::3] = np.nan
    plane[0, :6] = [0.5, 1.5, 2.5, -0.4, 65535.4, 65535.6]
    factor = rng.uniform(0.5, 1.5, plane.shape).astype(np.float32)

    def reference(x: np.ndarray, top: int) -> np.ndarray:
        return np.minimum(np.rint(np.fmax(x, np.float32(0))), top)

    assert np.array_equal(scaled_u16(plane, 1.0), reference(plane, 65535))
    assert list(scaled_u16(plane, 1.0)[0, :6]) == [0, 2, 2, 0, 65535, 65535]
    assert np.array_equal(scaled_u16(plane, factor), reference(plane * factor, 65535))
    small = plane / np.float32(200)
    assert np.array_equal(scaled_u8(small, 0.5), reference(small * np.float32(0.5), 255))
    for factor in (0.37, 1 / 3, 2.9):  # rounded from the float32 product, as the reference
        assert np.array_equal(scaled_u8(small, factor), reference(small * np.float32(factor), 255))
    assert not scaled_u8(np.float32([[np.inf, -np.inf, np.nan, -1e9]]), 1.0).any()
    assert scaled_u8(small, 1.0).dtype == np.uint8 and scaled_u16(plane, 1.0).dtype == np.uint16
    assert not scaled_u16(np.float32([[np.inf, -np.inf]]), 1.0).any()
    frame, z_mm = millimetre_frame(3)
    ray_z = K4A.unit_rays()[..., 2].astype(np.float32)
    assert np.array_equal(scaled_u16(frame.range_m, units_per_range_m(ray_z, 1e-3)), z_mm)


def test_png_decodes_exactly_with_libpng_and_refuses_what_it_cannot_hold():
    """tofd's PNG writer (Sub filter, ISA-L deflate) read back by OpenCV's libpng, bit for bit: every depth, odd
    sizes, one pixel, the extremes, a crop that is a view, and a plane's runs of zeros; a mask (bool) as 1-bit
    black and white, which libpng gives back as 0 and 255."""
    rng = np.random.default_rng(5)
    planes = [rng.integers(0, 65536, (7, 13)).astype(np.uint16), rng.integers(0, 256, (13, 7)).astype(np.uint8),
              np.array([[65535]], np.uint16), np.array([[0, 255]], np.uint8),
              rng.integers(0, 65536, (40, 50)).astype(np.uint16)[5:30:2, 3:41:3],  # strided view
              np.pad(rng.integers(900, 1100, (30, 40)).astype(np.uint16), 20)]
    for plane in planes:
        decoded = unpng(png(plane))
        assert decoded.dtype == plane.dtype and np.array_equal(decoded, plane)
    for mask in (rng.random((9, 13)) < 0.5, np.ones((1, 1), bool), rng.random((40, 64)) < 0.1,
                 (rng.random((50, 70)) < 0.5)[3:47:2, 5:66:3]):  # widths not a multiple of 8; a strided view
        decoded = unpng(png(mask))
        assert decoded.dtype == np.uint8 and np.array_equal(decoded, np.where(mask, 255, 0))
        assert len(png(mask)) < len(png(mask.astype(np.uint8))) or mask.size < 100
    for bad in (np.zeros((0, 4), np.uint8), np.zeros((3, 3), np.float32), np.zeros((2, 2, 3), np.uint8)):
        with pytest.raises(ValueError, match="PNG of a"):
            png(bad)


def test_the_amplitude_for_viewing_is_within_half_a_level_of_its_recorded_scale():
    """8 bits, the positive amplitudes' 99.5th percentile the brightest level: each pixel's level times the scale
    is its amplitude within half a level (brighter ones saturate at 255); NaN and negatives are 0; the JPEG keeps
    the levels within about one."""
    rng = np.random.default_rng(3)
    amplitude = rng.gamma(2.0, 700.0, K4A.shape).astype(np.float32)
    amplitude[:5, :5], amplitude[5:10, :5] = np.nan, -3.0
    levels, scale = amplitude_u8(amplitude)
    assert levels.dtype == np.uint8 and levels.shape == K4A.shape
    assert scale == pytest.approx(np.percentile(amplitude[amplitude > 0], 99.5) / 255, rel=0.02)
    sample = amplitude[::AMPLITUDE_SAMPLE_STEP, ::AMPLITUDE_SAMPLE_STEP]
    positive = np.sort(sample[sample > 0])  # the nearest rank of the sampled positive amplitudes, exactly
    assert scale == float(positive[round(0.995 * (positive.size - 1))]) / 255
    shown = levels * scale
    below = np.nan_to_num(amplitude) <= 255 * scale
    assert np.all(np.abs(shown[below] - np.fmax(np.nan_to_num(amplitude[below]), 0)) <= scale / 2 + 1e-3 * scale)
    assert np.all(levels[~below] == 255) and 0 < (~below).mean() < 0.01
    assert not levels[:10, :5].any()
    decoded = unpng(jpeg(levels)).astype(np.float64)
    assert np.sqrt(np.mean((decoded - levels) ** 2)) < 4  # white noise: JPEG's worst case
    assert amplitude_u8(np.full((4, 4), np.nan, np.float32))[1] == 1.0  # nothing positive: scale 1
    assert amplitude_u8(np.float32([[-2.0, 0.0], [np.nan, 0.0]]))[1] == 1.0


@pytest.mark.parametrize("fill, region", [(0.01, np.s_[:, :]), (0.3, np.s_[:, :]), (1.0, np.s_[:, :]),
                                          (0.5, np.s_[101:400, 203:518])])  # a box off the grid's origin
def test_the_cloud_is_every_pixel_of_a_small_foreground_and_an_even_grid_of_a_large_one(fill, region):
    mask = np.zeros(K4A.shape, bool)
    mask[region] = np.random.default_rng(1).random(K4A.shape)[region] < fill
    at = cloud_pixels(mask)
    assert len(at) <= CLOUD_POINTS and mask.reshape(-1)[at].all() and np.all(np.diff(at) > 0)
    if mask.sum() <= CLOUD_POINTS:
        assert len(at) == mask.sum()
    else:  # every k-th row and column of the mask, k the least that fits
        rows, cols = np.divmod(at, K4A.width)
        step = np.gcd.reduce(np.r_[rows, cols])
        assert step > 1 and len(at) == mask[::step, ::step].sum() > CLOUD_POINTS / 4
        assert mask[:: step - 1, :: step - 1].sum() > CLOUD_POINTS


def test_foxglove_range_of_a_millimetre_camera_is_its_millimetres_and_lines_up_with_the_cloud():
    cfg = parse_foxglove_spec("127.0.0.1:0", replace(Config(), intrinsics=K4A))
    publisher = FoxglovePublisher(cfg)
    mask = np.zeros(K4A.shape, bool)
    mask[150:450, 200:500] = True  # 90000 pixels: the cloud is a subsample
    feats = {name: np.where(mask, np.float32(2.0), np.float32(np.nan)) for name in bp.FEATURES}
    frames = [millimetre_frame(k) for k in range(3)]
    box = foreground_box(mask)
    try:
        publisher(FrameResult(0, frames[0][0], mask, feats, 0, 0.0, arrival_s=0.0, box=box))  # the server listens now
        client = Client(publisher.web_url)
        feature = t.FEATURES["range_nfft_eps0"]
        client.subscribe([t.RANGE, t.FOREGROUND, t.CALIBRATION, t.NOSE, feature, t.FEATURE_BOX])
        client.read(0.5)  # the subscriptions are in
        for frame, _ in frames[1:]:
            publisher(FrameResult(0, frame, mask, feats, 0, 0.0, arrival_s=0.0, box=box))
        got = client.read(10, until=lambda got: len(got.get(t.NOSE, [])) == 2)
        meta = next(c for c in client.channels.values() if c["topic"] == t.RANGE)["metadata"]
        client.close()
    finally:
        publisher.close(1.0)
    assert set(got) == {t.RANGE, t.FOREGROUND, t.CALIBRATION, t.NOSE, feature, t.FEATURE_BOX}  # nothing else
    for (_, image), (_, box) in zip(got[feature], got[t.FEATURE_BOX], strict=True):  # the mask's box, placed
        assert (box["x"], box["y"], box["width"], box["height"]) == (200, 150, 300, 300)
        assert box["top"][feature] == 2.0 and np.all(unpng(image.data) == 255)  # 255: the top value, 2.0
    assert meta == {"depth": "z", "unit_m": "0.001"}
    k = np.array(got[t.CALIBRATION][-1][1].K).reshape(3, 3)
    for (_, image), (_, cloud), (_, z_mm) in zip(got[t.RANGE], got[t.FOREGROUND], frames[1:], strict=True):
        assert image.format == "png"
        depth = unpng(image.data)
        np.testing.assert_array_equal(depth, z_mm)  # exactly the camera's millimetres
        points = np.frombuffer(cloud.data, "<f4").reshape(-1, 4)[:, :3].astype(np.float64)
        assert len(points) == len(cloud_pixels(mask)) <= CLOUD_POINTS
        uvw = points @ k.T  # each point through the calibration lands on its pixel, at that pixel's depth
        rows, cols = np.divmod(cloud_pixels(mask), K4A.width)
        np.testing.assert_allclose(uvw[:, 0] / uvw[:, 2], cols, atol=1e-3)
        np.testing.assert_allclose(uvw[:, 1] / uvw[:, 2], rows, atol=1e-3)
        np.testing.assert_allclose(points[:, 2], depth[rows, cols] * 1e-3, atol=1e-6)
