"""How the viewers (Rerun, Foxglove) carry a frame's planes: depth in its source's unit, amplitude for viewing.

A camera that measures z-depth in whole units (millimetres: Azure Kinect, RealSense, Orbbec; SensorInfo's
depth_unit_m) is shown as uint16 z-depth in that unit, which is lossless. The SR3000 measures radial range in whole
codes (c / (2 f_mod) / 65535, 0.11 mm at 20 MHz); its z-depth (range times the ray's z) is shown as uint16 in that
code, rounded: within half a code, the sensor's own resolution (Rerun; Foxglove gets the radial codes
themselves, its channel's metadata saying so). A source with no unit (rendered or float frames) is shown as float32
metres.
PNG is what both viewers decode: written here with rows Sub-filtered (one filter, the one that suits a smooth
surface) and deflated by ISA-L (python-isal), about three times faster than libpng with zlib's fastest level at the
same size on noisy depth (bench_viewers' encodings); the container is PNG's four fixed chunks.
The amplitude is for looking at: 8 bits scaled so a robust top (AMPLITUDE_PERCENTILE) is the brightest level, the
scale (sensor units per level) sent beside it, as a JPEG; a lossless 16-bit amplitude would cost about as much as
the depth for noise the eye does not see (tofd's own recordings keep it exactly). A feature map's crop is for
looking at too: 8 bits, its largest value the brightest level (that value sent beside it).
"""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
from isal import isal_zlib

from tofd.drivers import sr3000
from tofd.drivers.frame import Frame

PNG_MEDIA_TYPE = "image/png"
PNG_DEFLATE_LEVEL = 3  # ISA-L's levels 0-3 take about the same time; 3 makes the smallest files
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_SUB_FILTER = 1  # the filter byte of a row whose bytes are each the difference to the pixel to their left
WHOLE_UNIT_TOLERANCE = 0.05
"""A z-depth within this many units of a whole number is that number (float32 round-off of the driver's
unit -> radial range -> z-depth conversion is far below it)."""
U16_MAX = 65535
JPEG_MEDIA_TYPE = "image/jpeg"
JPEG_QUALITY = 95
"""Quality of the amplitude's JPEG: its error is about one 8-bit level rms, far below the sensor's noise (q 90
saves about a third of the bytes for about twice that error; bench_viewers measures both)."""
AMPLITUDE_PERCENTILE = 99.5
"""Percentile of the positive amplitudes shown as the brightest 8-bit level (a few specular pixels saturate)."""
AMPLITUDE_LEVELS = 255
AMPLITUDE_SAMPLE_STEP = 3
"""The amplitude's top (AMPLITUDE_PERCENTILE) is taken over every this-many-th row and column: the same top within
about a percent, for a ninth of the work."""


def source_unit_m(frame: Frame) -> float | None:
    """Metres per step of the source's integer depth (SensorInfo.depth_unit_m), None when the source gives
    float metres or does not say (no SensorInfo: the SR3000 and rendered frames)."""
    unit = None if frame.sensor is None else frame.sensor.depth_unit_m
    return unit if unit is not None and unit < 1.0 else None


def code_unit_m(frame: Frame) -> float | None:
    """Metres per step of an SR3000's radial range codes (its non-ambiguity range / 65535 at the frame's
    modulation frequency), None for other sources."""
    if frame.registers is None:
        return None
    return sr3000.non_ambiguity_range_m(sr3000.mod_freq_khz(frame.registers.mod_freq_index)) / U16_MAX


def z_depth_m(range_m: np.ndarray, ray_z: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 z-depth in metres (0 where the range is NaN) of radial ranges along rays of z `ray_z`."""
    depth = np.fmax(range_m, np.float32(0), out=out)  # fmax drops NaN; ranges are >= 0
    return np.multiply(depth, ray_z, out=depth)


def scaled_u16(plane: np.ndarray, factor: float | np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(H, W) uint16 of the float32 `plane` times `factor` (a number, or (H, W) float32 per pixel), rounded to the
    nearest integer (ties to even), 0 where that is NaN, infinite or negative, 65535 above, written to `out` (a
    C-contiguous (H, W) uint16) if given: one pass, OpenCV's saturating multiply (numpy takes five passes)."""
    scale = factor if isinstance(factor, np.ndarray) else (float(factor),)
    product: np.ndarray = cv2.multiply(plane, scale, dst=out, dtype=cv2.CV_16U)  # type: ignore[arg-type]  # stubs lack Scalar
    return product


def scaled_u8(plane: np.ndarray, factor: float) -> np.ndarray:
    """(H, W) uint8 of the float32 `plane` times `factor` (their float32 product rounded to the nearest integer, ties
    to even), 0 where that is NaN, infinite or negative, 255 above."""
    return _levels(np.fmax(plane, np.float32(0)), factor)  # fmax drops NaN


def _levels(plane: np.ndarray, factor: float) -> np.ndarray:
    """scaled_u8 of a plane with no negative or NaN values: OpenCV's convertScaleAbs, a vectorised pass several times
    as fast as its multiply by a number into uint8 (the absolute value it takes changes nothing here)."""
    levels: np.ndarray = cv2.convertScaleAbs(plane, alpha=float(factor))
    return levels


def in_units(z_m: np.ndarray, unit_m: float) -> tuple[np.ndarray, bool]:
    """(H, W) uint16 z-depth in units of `unit_m` (scaled_u16) of `z_m` (metres, 0: no return), and whether that
    is exact: every pixel a whole number of units below 65536."""
    units = z_m * np.float32(1.0 / unit_m)
    whole = np.rint(units)
    exact = (float(np.max(np.abs(units - whole), initial=0.0)) <= WHOLE_UNIT_TOLERANCE
             and float(whole.max(initial=0.0)) <= U16_MAX)
    return scaled_u16(z_m, 1.0 / unit_m), exact


def units_per_range_m(ray_z: np.ndarray, unit_m: float) -> np.ndarray:
    """(H, W) float32 factor from a pixel's radial range in metres to its z-depth in units of `unit_m` (ray z /
    unit): scaled_u16(range_m, it) is in_units(z_depth_m(range_m, ray_z), unit_m)[0] in one pass."""
    return (ray_z / np.float32(unit_m)).astype(np.float32)


def exact_z_units(frame: Frame, ray_z: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The source's unit (metres) and the (H, W) factor from radial range to z-depth in it (units_per_range_m) when
    the frame's z-depth is a whole number of that unit at every pixel (in_units); None when the source gives no
    unit or its z-depth is not whole in it."""
    unit = source_unit_m(frame)
    if unit is None or not in_units(z_depth_m(frame.range_m, ray_z), unit)[1]:
        return None
    return unit, units_per_range_m(ray_z, unit)


def radial_code_unit(frame: Frame) -> float | None:
    """The SR3000's code unit (code_unit_m) when the frame's radial ranges are whole codes of it, as its driver
    delivers them; else None."""
    code = code_unit_m(frame)
    if code is None or not in_units(np.fmax(frame.range_m, np.float32(0)), code)[1]:
        return None
    return code


def z_units(frame: Frame, ray_z: np.ndarray) -> tuple[float, np.ndarray] | None:
    """The unit (metres) a viewer's uint16 z-depth is in and the (H, W) factor from radial range to z-depth in it
    (units_per_range_m): the source's own where its z-depth is whole in it (exact_z_units), else the SR3000's code
    where its ranges are whole codes (radial_code_unit; z-depth rounded to a code); None: float32 metres. Decided
    at a run's first frame."""
    exact = exact_z_units(frame, ray_z)
    if exact is not None:
        return exact
    code = radial_code_unit(frame)
    return None if code is None else (code, units_per_range_m(ray_z, code))


def amplitude_u16(amplitude: np.ndarray) -> np.ndarray:
    """(H, W) uint16 amplitude: sensor units rounded to integers (scaled_u16), NaN and negatives 0, clipped at
    65535."""
    return scaled_u16(amplitude, 1.0)


def amplitude_u8(amplitude: np.ndarray) -> tuple[np.ndarray, float]:
    """(H, W) uint8 amplitude for viewing and its scale, sensor units per level: AMPLITUDE_PERCENTILE of the
    positive amplitudes (of a grid of them: AMPLITUDE_SAMPLE_STEP; nearest rank, by a partial sort: np.percentile
    costs several times as much) is level AMPLITUDE_LEVELS, brighter pixels saturate; NaN and negatives are 0. Scale
    1 when nothing is positive."""
    sample = amplitude[::AMPLITUDE_SAMPLE_STEP, ::AMPLITUDE_SAMPLE_STEP]
    positive = sample[sample > 0]  # False for NaN
    rank = round(AMPLITUDE_PERCENTILE / 100 * (positive.size - 1))
    top = float(np.partition(positive, rank)[rank]) if positive.size else 0.0
    scale = top / AMPLITUDE_LEVELS if top > 0 else 1.0
    return scaled_u8(amplitude, 1.0 / scale), scale


FEATURE_LEVELS = 255


def feature_u8(values: np.ndarray) -> tuple[np.ndarray, float]:
    """(h, w) uint8 of a feature map's crop for viewing (>= 0, NaN outside the foreground -> 0), FEATURE_LEVELS its
    largest value, and that value (0: none; a level is top / FEATURE_LEVELS): the viewers show it colour-mapped,
    where 256 colours are all a map shows."""
    clean = np.fmax(values, np.float32(0))  # fmax drops NaN
    top = float(clean.max(initial=0.0))
    if top <= 0:
        return np.zeros(values.shape, np.uint8), top
    return _levels(clean, FEATURE_LEVELS / top), top


def jpeg(plane: np.ndarray) -> bytes:
    """The JPEG (JPEG_QUALITY) of a (H, W) uint8 plane (greyscale)."""
    ok, encoded = cv2.imencode(".jpg", np.ascontiguousarray(plane), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"JPEG encoding of a {plane.dtype} {plane.shape} plane failed")
    return encoded.tobytes()


def png(plane: np.ndarray) -> bytes:
    """The lossless PNG (greyscale: 1, 8 or 16 bits) of a (H, W) bool, uint8 or uint16 plane, H and W >= 1 (a bool
    plane, a mask, is black and white: PNG's 1-bit greyscale, an eighth of its bytes)."""
    if plane.ndim != 2 or plane.dtype not in (np.bool_, np.uint8, np.uint16) or 0 in plane.shape:
        raise ValueError(f"PNG of a {plane.dtype} {plane.shape} plane: expected a non-empty (H, W) bool, uint8 or "
                         "uint16")
    height, width = plane.shape
    if plane.dtype == np.bool_:
        rows, bits, depth = np.packbits(plane, axis=1), 1, 1  # PNG packs pixels from each byte's top bit
    else:
        depth = plane.dtype.itemsize  # bytes per pixel
        rows = np.ascontiguousarray(plane, ">u2" if depth == 2 else np.uint8).view(np.uint8).reshape(height, -1)
        bits = 8 * depth
    filtered = np.empty((height, 1 + rows.shape[1]), np.uint8)
    filtered[:, 0] = PNG_SUB_FILTER
    filtered[:, 1:1 + depth] = rows[:, :depth]  # the first pixel (byte, below 8 bits) has nothing to its left
    np.subtract(rows[:, depth:], rows[:, :-depth], out=filtered[:, 1 + depth:])  # modulo 256, as PNG's Sub
    header = struct.pack(">IIBBBBB", width, height, bits, 0, 0, 0, 0)  # greyscale, deflate, no interlace
    return b"".join((PNG_SIGNATURE, _png_chunk(b"IHDR", header),
                     _png_chunk(b"IDAT", isal_zlib.compress(filtered, PNG_DEFLATE_LEVEL)), _png_chunk(b"IEND", b"")))


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    """A PNG chunk: length, type, data, CRC-32 of type and data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def unpng(data: bytes) -> np.ndarray:
    """The (H, W) plane of a one-channel PNG or JPEG (its own dtype)."""
    plane = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if plane is None:
        raise ValueError("not a PNG or JPEG image")
    return plane
