"""Logs FrameResults to a Rerun RecordingStream (entity tree in blueprint.py); runs on the sink thread.

Per frame: z-depth under the Pinhole (what Rerun's depth images mean, so the 3-D projection is right; the camera's
radial range is it over each ray's z) as uint16 in the source's unit where it has one, else float32 metres
(tofd.service.viewer.encoding.z_units), a PNG when larger than RAW_DEPTH_PIXELS; amplitude for viewing as an 8-bit
JPEG (its scale, sensor units per level, a time series beside it: encoding.amplitude_u8); the mask and four feature
maps cropped to the foreground's bounding box (they are 0 outside it) with the translation that puts each crop
where it lies in the image, as raw 8-bit images (Rerun's chunk compression shrinks them; its viewer plays encoded
images as a video stream, whose size must not change): the maps as depth images whose meter (levels per unit)
gives their values back (encoding.feature_u8); the foreground cloud (at most pixels.CLOUD_POINTS points, an even
subsample of a large foreground), the detected nose in 2-D and 3-D, beside it the confirmed nose track (a box of
pixels.TRACK_BOX_M about its pixel, labelled with its confidence, and its 3-D point) and the track's confidence,
the stage timings (one entity, a series per stage in TIMED_STAGES' order: one send for all).
Timelines: `frame` (device frame counter) and `device_time` (device clock).

Everything per frame goes out as columns (Rerun's send_columns), `batch_frames` frames per send: a log call
costs about four times the CPU of its share of a batched send, and on two cores that CPU is the feature
workers'. Lossless runs and files batch (frames_per_send); live runs to a viewer send what the views show each
frame at once, so the viewer is never behind, and the time series SERIES_FRAMES at once (a plot can lag).
Images go out as ready arrow columns (tofd.service.viewer.columns). A missing nose or track is a row with no
points (nothing drawn); styles that never change (colour maps, metres, radii, colours) are logged once, static.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cache

import numpy as np
import pyarrow as pa
import rerun as rr

from tofd.algorithm.names import FAMILY_TABLE
from tofd.config import RerunConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.service.pipeline.results import FrameResult
from tofd.service.pipeline.stats import TIMED_STAGES
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.columns import (
    blobs,
    component_array,
    component_type,
    image_columns,
    image_format,
    image_formats,
    offsets_of,
    row_columns,
)
from tofd.service.viewer.encoding import (
    FEATURE_LEVELS,
    JPEG_MEDIA_TYPE,
    PNG_MEDIA_TYPE,
    amplitude_u8,
    feature_u8,
    jpeg,
    png,
    scaled_u16,
    z_depth_m,
    z_units,
)
from tofd.service.viewer.pixels import cloud_grid, corner_origin, shown_box, track_box_px
from tofd.service.viewer.wire import OWN_TIMINGS

POINT_COLOUR_MAP = FAMILY_TABLE["range_nfft"].map_name("eps0")  # the foreground's 3-D points take its view's colours
NOSE_COLOR = (255, 0, 255)
TRACK_COLOR = (0, 200, 255)
MAX_BATCH_AGE_S = 0.5  # a batch is sent once its first frame waited this long, however few frames it holds
SERIES_FRAMES = 15  # the time series (stage timings, track confidence) go out at least this many frames at once
LOGGING, LATENCY = (TIMED_STAGES.index(stage) for stage in OWN_TIMINGS)  # the timings this process measures
RAW_DEPTH_PIXELS = 320 * 240
"""A uint16 depth of at most this many pixels goes raw: its PNG's deflate would cost the viewer more CPU than
Rerun's file writer spends on the bytes it saves; a larger one (640x576) goes as a PNG, as raw it would take 1.5 to
2 times the bytes (Rerun's LZ4 chunk compression does not shrink noisy depth)."""


def frames_per_send(cfg: RerunConfig, policy: str) -> int:
    """Frames per column send: cfg.batch_frames for lossless runs (replay) and into a file, 1 for live runs
    ("latest") to a viewer, which should show each frame as soon as it is done."""
    return cfg.batch_frames if policy == "lossless" or cfg.sink == "save" else 1


@cache
def viridis_rgba() -> np.ndarray:
    """(256,) uint32 lookup table of the viridis colour map, packed 0xRRGGBBAA (Rerun's colour type)."""
    from matplotlib import colormaps

    rgb = (colormaps["viridis"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint32)
    return (rgb[:, 0] << 24) | (rgb[:, 1] << 16) | (rgb[:, 2] << 8) | 0xFF


@dataclass(frozen=True, slots=True)
class ImageEntity:
    """A per-frame full-frame image sent as raw pixels: its archetype and pixel type."""

    archetype: type
    dtype: type


CROPPED = {bp.MASK: rr.SegmentationImage, **dict.fromkeys(bp.FEATURES.values(), rr.DepthImage)}
"""Entities sent over the foreground's box only, as uint8 images: their archetypes."""

# entities with a variable number of instances per frame (0 = none): archetype, static style
PARTS: dict[str, tuple[type, rr.AsComponents | None]] = {
    bp.FOREGROUND: (rr.Points3D, rr.Points3D.from_fields(radii=0.002)),
    bp.NOSE_2D: (rr.Points2D, rr.Points2D.from_fields(radii=3, colors=[NOSE_COLOR], labels="nose")),
    bp.NOSE_3D: (rr.Points3D, rr.Points3D.from_fields(radii=0.01, colors=[NOSE_COLOR])),
    bp.TRACK_2D: (rr.Boxes2D, rr.Boxes2D.from_fields(colors=[TRACK_COLOR])),
    bp.TRACK_3D: (rr.Points3D, rr.Points3D.from_fields(radii=0.006, colors=[TRACK_COLOR])),
    bp.TRACK_CONFIDENCE: (rr.Scalars, None),
    bp.AMPLITUDE_SCALE: (rr.Scalars, rr.SeriesLines(names="amplitude units per level")),
    bp.TIMINGS: (rr.Scalars, rr.SeriesLines(names=[f"{stage} [ms]" for stage in TIMED_STAGES])),
}


@dataclass(slots=True)
class Batch:
    """Frames not yet sent: their counters and device times, and the rows of each PARTS entity."""

    opened_s: float = 0.0  # monotonic: when its first frame came
    frames: list[int] = field(default_factory=list)
    device_s: list[float] = field(default_factory=list)
    parts: dict[str, list[tuple[int, dict[str, np.ndarray | list]]]] = field(default_factory=dict)
    indexes: list[rr.TimeColumn] | None = None  # the time columns of all its frames, once built

    def open_row(self, frame_counter: int, device_s: float) -> int:
        """Append a frame; its row."""
        if not self.frames:
            self.opened_s = time.monotonic()
        self.frames.append(frame_counter)
        self.device_s.append(device_s)
        return len(self.frames) - 1

    def add(self, path: str, row: int, **components: np.ndarray | list) -> None:
        """Frame `row`'s instances of a PARTS entity: each component has one entry per instance."""
        self.parts.setdefault(path, []).append((row, components))

    def time_columns(self, rows: Sequence[int]) -> list[rr.TimeColumn]:
        """The `frame` and `device_time` columns of frames `rows` (built once for all the batch's frames, the rows
        of every image)."""
        every = len(rows) == len(self.frames)
        if every and self.indexes is not None:
            return self.indexes
        at = np.asarray(rows, np.intp)
        indexes = [rr.TimeColumn("frame", sequence=np.asarray(self.frames, np.int64)[at]),
                   rr.TimeColumn("device_time", duration=np.asarray(self.device_s, np.float64)[at])]
        if every:
            self.indexes = indexes
        return indexes

    def due(self, frames: int) -> bool:
        """It holds `frames` frames, or its first one waited MAX_BATCH_AGE_S."""
        return len(self.frames) >= frames or (bool(self.frames) and time.monotonic() - self.opened_s >= MAX_BATCH_AGE_S)


@dataclass(slots=True)
class Shown(Batch):
    """The batch of what the views show per frame (images, points, boxes), with each frame's arrival, own
    logging time and row in the series batch."""

    images: dict[str, np.ndarray] = field(default_factory=dict)  # entity -> (batch_frames, H, W), row per frame
    crops: dict[str, list[np.ndarray]] = field(default_factory=dict)  # CROPPED entity -> its uint8 crop per frame
    encoded: dict[str, list[bytes]] = field(default_factory=dict)  # entity -> its PNG or JPEG per frame
    feature_meters: dict[str, list[float]] = field(default_factory=dict)  # feature entity -> levels per unit
    corners: list[tuple[int, int]] = field(default_factory=list)  # per frame: the crops' top-left pixel (x, y)
    arrival_s: list[float] = field(default_factory=list)
    call_ms: list[float] = field(default_factory=list)
    stage_ms: list[list[float]] = field(default_factory=list)  # per frame: its timings in TIMED_STAGES' order
    series_row: list[int] = field(default_factory=list)


class RerunLogger:
    """Callable sink: logs static entities once at construction, then every FrameResult it is given, sending
    them `batch_frames` at a time (flush() sends what waits; call it before closing the stream)."""

    def __init__(self, rec: rr.RecordingStream, intrinsics: Intrinsics, point_cloud: bool = True,
                 batch_frames: int = 1):
        self.rec, self.point_cloud, self.batch_frames = rec, point_cloud, batch_frames
        self.intrinsics = intrinsics
        self._rays = intrinsics.unit_rays().astype(np.float32)
        self._ray_z = np.ascontiguousarray(self._rays[..., 2])  # z-depth = radial range * cos(angle to the axis)
        self._images: dict[str, ImageEntity] = {}  # raw full-frame planes: the depth, unless it goes as PNG
        self._crop_format = image_format(height=1, width=1, color_model=None, dtype=np.uint8)  # sized: image_formats
        # encoded planes: archetype; the depth's joins at the first frame if it goes as PNG
        self._encoded: dict[str, type] = {bp.AMPLITUDE: rr.EncodedImage}
        self._units_per_range: np.ndarray | None = None  # (H, W) radial metres -> depth units, when it goes as uint16
        self._depth_chosen = False
        self._shape = intrinsics.shape
        self._formats: dict[str, pa.StructArray] = {}  # raw images' format, as arrow: Rerun's conversion is slow
        self._format_columns: dict[tuple[str, int], pa.Array] = {}
        self._shown, self._series = self._new_shown(), Batch()
        rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)
        rec.log(bp.CAMERA, rr.Pinhole(focal_length=[intrinsics.fx, intrinsics.fy],
                                      principal_point=corner_origin((intrinsics.cx, intrinsics.cy)),
                                      width=intrinsics.width, height=intrinsics.height), static=True)
        rec.log(bp.MASK, rr.AnnotationContext([(0, "background", (0, 0, 0)), (1, "foreground", (230, 60, 40))]),
                static=True)
        styles = {# a depth image is Rerun's colour-mapped scalar image; the eccentricities are not depths
                  **dict.fromkeys(bp.FEATURES.values(), rr.DepthImage.from_fields(colormap="viridis")),
                  bp.AMPLITUDE: rr.EncodedImage.from_fields(media_type=JPEG_MEDIA_TYPE),
                  **{path: style for path, (_, style) in PARTS.items()}}
        for path, style in styles.items():
            if style is not None:
                rec.log(path, style, static=True)

    @property
    def pending(self) -> int:
        """Frames logged but not yet sent to the views."""
        return len(self._shown.frames)

    def __call__(self, r: FrameResult) -> None:
        t0 = time.perf_counter()
        frame, shown, series = r.frame, self._shown, self._series
        device_s = frame.timestamp_us * 1e-6
        row = shown.open_row(frame.frame_counter, device_s)
        shown.series_row.append(series.open_row(frame.frame_counter, device_s))
        shown.arrival_s.append(r.arrival_s)
        if r.gap_before:
            self.rec.set_time("frame", sequence=frame.frame_counter)  # thread-local: set on the logging thread
            self.rec.set_time("device_time", duration=device_s)
            self.rec.log(bp.EVENTS, rr.TextLog(f"{r.gap_before} before frame {frame.frame_counter}",
                                               level=rr.TextLogLevel.WARN))
        self._add_planes(r, row)
        box = shown_box(r.box)
        shown.corners.append((box[1].start, box[0].start))
        shown.crops.setdefault(bp.MASK, []).append(r.mask[box].astype(np.uint8))  # a copy: the slot is written again
        for name, path in bp.FEATURES.items():  # eccentricities are >= 0; NaN outside the foreground
            levels, top = feature_u8(r.features[name][box])
            shown.crops.setdefault(path, []).append(levels)
            shown.feature_meters.setdefault(path, []).append(FEATURE_LEVELS / top if top > 0 else 1.0)
        if self.point_cloud:
            rows, cols = cloud_grid(r.mask, box=r.box)
            at = rows * frame.range_m.shape[1] + cols  # np.take of a flat index: far faster than a 2-D fancy index
            ranges = np.take(frame.range_m.reshape(-1), at)
            levels = shown.crops[bp.FEATURES[POINT_COLOUR_MAP]][-1]  # each point's colour in that map's view
            shown.add(bp.FOREGROUND, row, positions=np.take(self._rays.reshape(-1, 3), at, axis=0) * ranges[:, None],
                      colors=np.take(viridis_rgba(), levels[rows - box[0].start, cols - box[1].start]))
        self._add_nose_and_track(r, row, shown.series_row[row])
        shown.stage_ms.append([r.timings_ms.get(stage, np.nan) for stage in TIMED_STAGES])  # own ones: at the send
        shown.call_ms.append((time.perf_counter() - t0) * 1e3)
        if series.due(max(self.batch_frames, SERIES_FRAMES)):
            self.flush()  # the views' batch first: its frames' logging times and latencies join the series
        elif shown.due(self.batch_frames):
            self._send_shown()

    def _add_planes(self, r: FrameResult, row: int) -> None:
        """The frame's depth (z-depth: uint16 in the source's unit, raw or PNG, or float32 metres) and amplitude
        (8-bit JPEG and its scale)."""
        shown = self._shown
        if not self._depth_chosen:
            self._choose_depth(r)
        if self._units_per_range is None:
            z_depth_m(r.frame.range_m, self._ray_z, out=shown.images[bp.RANGE][row])
        elif bp.RANGE in self._images:
            scaled_u16(r.frame.range_m, self._units_per_range, out=shown.images[bp.RANGE][row])
        else:
            shown.encoded.setdefault(bp.RANGE, []).append(png(scaled_u16(r.frame.range_m, self._units_per_range)))
        amplitude, scale = amplitude_u8(r.frame.amplitude)
        shown.encoded.setdefault(bp.AMPLITUDE, []).append(jpeg(amplitude))
        shown.add(bp.AMPLITUDE_SCALE, row, scalars=[scale])  # with its image, not with the lagging series

    def _choose_depth(self, r: FrameResult) -> None:
        """At the first frame: the depth goes as uint16 in the source's unit where it has one (encoding.z_units),
        raw up to RAW_DEPTH_PIXELS, else as a PNG, and as float32 metres where it has none; its static style (metre,
        colour map)."""
        units = z_units(r.frame, self._ray_z)
        unit = 1.0
        if units is not None:
            unit, self._units_per_range = units
        height, width = self._shape
        style: rr.AsComponents
        if units is not None and height * width > RAW_DEPTH_PIXELS:
            self._encoded[bp.RANGE] = rr.EncodedDepthImage
            style = rr.EncodedDepthImage.from_fields(media_type=PNG_MEDIA_TYPE, meter=1.0 / unit, colormap="turbo")
        else:
            dtype: type = np.float32 if units is None else np.uint16
            self._images[bp.RANGE] = ImageEntity(rr.DepthImage, dtype)
            self._formats[bp.RANGE] = image_format(height=height, width=width, color_model=None, dtype=dtype)
            self._shown.images[bp.RANGE] = np.empty((self.batch_frames, *self._shape), dtype)
            style = rr.DepthImage.from_fields(meter=1.0 / unit, colormap="turbo")
        self.rec.log(bp.RANGE, style, static=True)
        self._depth_chosen = True

    def _add_nose_and_track(self, r: FrameResult, row: int, series_row: int) -> None:
        """The detected nose (its refined tip, else the accepted pixel; none: an empty row), and the confirmed track's
        box, point and confidence."""
        shown, det, track = self._shown, r.detection, r.track
        if det is not None:
            found = det.answer_px is not None
            shown.add(bp.NOSE_2D, row, positions=[corner_origin(det.answer_px)] if found else np.empty((0, 2)))
            shown.add(bp.NOSE_3D, row, positions=[det.answer_xyz_m] if found else np.empty((0, 3)))
        if track is None:
            return
        box = track_box_px(track, self.intrinsics)
        if box is not None and track.nose_xyz_m is not None:
            shown.add(bp.TRACK_2D, row, centers=[box[0]], half_sizes=[[box[1], box[1]]],
                      labels=[f"track {track.confidence:.2f}"])
            shown.add(bp.TRACK_3D, row, positions=[track.nose_xyz_m])
        else:
            shown.add(bp.TRACK_2D, row, centers=np.empty((0, 2)), half_sizes=np.empty((0, 2)),
                      labels=np.empty(0, str))
            shown.add(bp.TRACK_3D, row, positions=np.empty((0, 3)))
        self._series.add(bp.TRACK_CONFIDENCE, series_row, scalars=[track.confidence])

    def flush(self) -> None:
        """Send everything that waits."""
        self._send_shown()
        series, self._series = self._series, Batch()
        self._send_parts(series)

    def _send_shown(self) -> None:
        """Send the views' batch; its frames' logging time (own share plus the send's) and latency join the
        series."""
        if not self._shown.frames:
            return
        b, self._shown = self._shown, self._new_shown()
        t0 = time.perf_counter()
        rows = range(len(b.frames))
        for path, image in self._images.items():
            frames = b.images[path][: len(rows)]
            self._send(path, b, rows, image_columns(
                image.archetype, blobs(frames.reshape(-1), np.full(len(rows), frames[0].size)),
                self._formats_of(path, len(rows))))
        self._send_crops(b, rows)
        for path, encoded in b.encoded.items():
            descriptor, datatype = component_type(self._encoded[path], "blob")
            flat = np.frombuffer(b"".join(encoded), np.uint8)
            self._send(path, b, rows, row_columns((descriptor, blobs(flat, [len(e) for e in encoded], datatype))))
        self._send_parts(b)
        share_ms = (time.perf_counter() - t0) * 1e3 / len(rows)
        now = time.monotonic()
        for i, at in enumerate(b.series_row):
            timings = b.stage_ms[i]
            timings[LOGGING], timings[LATENCY] = b.call_ms[i] + share_ms, (now - b.arrival_s[i]) * 1e3
            self._series.add(bp.TIMINGS, at, scalars=timings)

    def _send_crops(self, b: Shown, rows: Sequence[int]) -> None:
        """Send the CROPPED entities' crops, each with the translation that puts it back in the image (and a feature
        map's meter, levels per unit)."""
        if not b.corners:
            return
        descriptor, datatype = component_type(rr.Transform3D, "translation")
        place = (descriptor, component_array(datatype, np.c_[b.corners, np.zeros(len(b.corners))]))  # z = 0
        masks = b.crops[bp.MASK]  # every crop of a frame has its mask crop's shape
        formats = image_formats(self._crop_format, [mask.shape for mask in masks])
        sizes = [mask.size for mask in masks]
        for path, crops in b.crops.items():
            archetype, more = CROPPED[path], [place]
            if path in b.feature_meters:
                meter, meter_type = component_type(archetype, "meter")
                more.append((meter, component_array(meter_type, b.feature_meters[path])))
            flat = np.concatenate([crop.reshape(-1) for crop in crops])
            self._send(path, b, rows, image_columns(archetype, blobs(flat, sizes), formats, *more))

    def _formats_of(self, path: str, frames: int) -> pa.Array:
        """The entity's one image format, once per frame of a batch of `frames` (built once per length)."""
        key = (path, frames)
        if key not in self._format_columns:
            self._format_columns[key] = self._formats[path].take(np.zeros(frames, np.intp))
        return self._format_columns[key]

    def _new_shown(self) -> Shown:
        """An empty views' batch with fresh image buffers (Rerun keeps the sent ones: they are not copied)."""
        return Shown(images={path: np.empty((self.batch_frames, *self._shape), image.dtype)
                             for path, image in self._images.items()})

    def _send_parts(self, b: Batch) -> None:
        """send_columns of each PARTS entity of the batch, partitioned by frame."""
        for path, entries in b.parts.items():
            at, components = zip(*entries, strict=True)
            offsets = offsets_of([len(next(iter(c.values()))) for c in components])
            described = []
            for name in components[0]:
                descriptor, datatype = component_type(PARTS[path][0], name)
                values = np.concatenate([np.asarray(c[name]) for c in components])
                described.append((descriptor, component_array(datatype, values)))
            self._send(path, b, at, row_columns(*described, offsets=offsets))

    def _send(self, path: str, b: Batch, rows: Sequence[int], columns: Iterable[rr.ComponentColumn]) -> None:
        """send_columns of `columns` at the batch's frames `rows`, on both timelines."""
        self.rec.send_columns(path, indexes=b.time_columns(rows), columns=columns)
