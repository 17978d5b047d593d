"""Publishes FrameResults over the Foxglove WebSocket protocol (foxglove-sdk's server); runs in a viewer process.

The server is the SDK's own (Rust, its own threads): a log call encodes the message (protobuf) and queues it for
each subscribed client, at most `[foxglove] backlog_messages` per client (about three frames' messages), dropping
the client's oldest when its queue is full, so a slow client gets the latest frames, not a backlog; a log call
never waits for a client. A message is only made for a channel some client subscribed to (Channel.has_sinks).
The viewer process around it (tofd.service.viewer.process) keeps the pipeline from ever waiting on this one.
The server listens from the first frame on, with every channel open (the range's form is the first frame's): a
client that connects earlier is refused and reconnects, as Foxglove does, rather than miss a channel; its address
(port 0: one the system had free) is known, and checked, at start.

Per frame (topics.py): range (a 16-bit PNG in the source's unit where that is exact, else float metres),
amplitude for viewing as an 8-bit JPEG with its scale (encoding.amplitude_u8), the mask as PNG, the calibration,
the nose and the nose track as image annotations, the foreground as a point cloud (at most pixels.CLOUD_POINTS
points), the viewed feature maps as 8-bit PNGs of the foreground's box (its place and their levels beside them)
and the world -> camera transform; every message of a frame has the host's wall-clock time of its arrival as
timestamp and log time. The SDK's own log lines go to tofd's log, prefixed and limited (SDK_LOGGERS).
"""

from __future__ import annotations

import logging
import os
import socket
import stat
import threading
import time
from collections.abc import Iterator

import foxglove
import numpy as np
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    FrameTransformChannel,
    ImageAnnotationsChannel,
    PointCloudChannel,
    RawImageChannel,
)
from foxglove.messages import (
    CameraCalibration,
    Color,
    CompressedImage,
    FrameTransform,
    ImageAnnotations,
    KeyValuePair,
    PackedElementField,
    PackedElementFieldNumericType,
    Point2,
    PointCloud,
    PointsAnnotation,
    PointsAnnotationType,
    Quaternion,
    RawImage,
    TextAnnotation,
    Timestamp,
    Vector3,
)

from tofd.config import Config
from tofd.drivers.intrinsics import Intrinsics
from tofd.logs import limit_library_lines
from tofd.service.foxglove import topics as t
from tofd.service.foxglove.spec import listen_port
from tofd.service.pipeline.results import FrameResult
from tofd.service.viewer.encoding import (
    amplitude_u8,
    exact_z_units,
    feature_u8,
    jpeg,
    png,
    radial_code_unit,
    scaled_u16,
)
from tofd.service.viewer.pixels import cloud_pixels, corner_origin, shown_box, track_box_px

log = logging.getLogger(__name__)

SDK_LOGGERS = ("foxglove", "tungstenite")
"""The foxglove SDK's (Rust) loggers, bridged to Python's logging: prefixed and limited (tofd.logs.LimitedLines),
as a client's one bad request can make it log a line per item."""

NOSE_COLOR = Color(r=1.0, g=0.0, b=1.0, a=1.0)
TRACK_COLOR = Color(r=0.0, g=0.78, b=1.0, a=1.0)
STOP_WAIT_S = 1.0  # seconds close() waits for the clients' closing handshakes (readers finish in milliseconds)
NOSE_POINT_PX = 6.0  # diameter of the nose's point in the image, pixels
CLOUD_FIELDS = ("x", "y", "z", "eps0")  # float32 each: metres in CAMERA_FRAME, then NFFT eps0
CLOUD_DTYPE = np.dtype([(name, "<f4") for name in CLOUD_FIELDS])


def _png(stamp: Timestamp, plane: np.ndarray) -> CompressedImage:
    """A PNG CompressedImage in CAMERA_FRAME of a (H, W) uint8 or uint16 plane."""
    return CompressedImage(timestamp=stamp, frame_id=t.CAMERA_FRAME, data=png(plane), format="png")


def _json_stamp(stamp: Timestamp) -> dict[str, int]:
    """A Timestamp as the JSON topics carry it (their schemas' "timestamp")."""
    return {"sec": stamp.sec, "nsec": stamp.nsec}


def _image(stamp: Timestamp, plane: np.ndarray, encoding: str) -> RawImage:
    """A RawImage in CAMERA_FRAME of a C-contiguous (H, W) plane (little-endian, as x86 and ARM hosts are)."""
    height, width = plane.shape
    return RawImage(timestamp=stamp, frame_id=t.CAMERA_FRAME, width=width, height=height,
                                      encoding=encoding, step=width * plane.itemsize, data=plane.tobytes())


def cannot_listen(bind: str, port: int, reason: object) -> RuntimeError:
    """The error of a server that cannot listen on bind:port, naming the config keys."""
    return RuntimeError(f"foxglove: cannot listen on {bind}:{port} (foxglove.bind / foxglove.port): {reason}")


def tcp_sockets() -> Iterator[socket.socket]:
    """This process's TCP sockets (IPv4 and IPv6), each through a duplicate of its descriptor that is closed once
    the next is asked for; none where /proc/self/fd is not (Linux only)."""
    try:
        fds = [int(fd) for fd in os.listdir("/proc/self/fd")]
    except OSError:
        return
    for fd in fds:
        try:
            if not stat.S_ISSOCK(os.fstat(fd).st_mode):
                continue
            sock = socket.socket(fileno=os.dup(fd))
        except OSError:  # closed meanwhile
            continue
        with sock:
            if sock.family in (socket.AF_INET, socket.AF_INET6) and sock.type == socket.SOCK_STREAM:
                yield sock


def send_without_delay(port: int) -> bool:
    """Turn off Nagle's algorithm (TCP_NODELAY) on this process's socket listening on `port`; the sockets it accepts
    inherit it (Linux). foxglove-sdk leaves it on, so the small messages that end a frame waited for the client's
    delayed acknowledgement of the ones before (about 30 ms). False when no such socket was found."""
    for sock in tcp_sockets():
        if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ACCEPTCONN) and sock.getsockname()[1] == port:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return True
    return False


def calibration(intrinsics: Intrinsics, stamp: Timestamp) -> CameraCalibration:
    """The camera's CameraCalibration (no distortion): K and P in ROS's convention, (0, 0) the top-left pixel's
    centre, as tofd's intrinsics and recordings."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    return CameraCalibration(timestamp=stamp, frame_id=t.CAMERA_FRAME, width=intrinsics.width,
                             height=intrinsics.height, distortion_model="plumb_bob", D=[0.0] * 5,
                             K=[fx, 0, cx, 0, fy, cy, 0, 0, 1], R=[1, 0, 0, 0, 1, 0, 0, 0, 1],
                             P=[fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0])


class FoxglovePublisher:
    """A viewer process's backend (viewer.process.ViewerBackend): the Foxglove WebSocket server on
    cfg.foxglove's address (`web_url`; listening from the first frame on) and one channel per topic; call it with
    each frame."""

    def __init__(self, cfg: Config, sink: str = "foxglove", batch_frames: int = 1, footer: bool = False):
        fc = cfg.foxglove
        for name in SDK_LOGGERS:  # before the server starts, so its first lines go the same way
            limit_library_lines(name, "foxglove SDK: ")
        self.intrinsics = intrinsics = cfg.intrinsics
        self.context = ctx = foxglove.Context()  # our channels only: another server in this process sees none
        self.images = {topic: CompressedImageChannel(topic, context=ctx) for topic in (t.AMPLITUDE, t.MASK)}
        self.features = {name: CompressedImageChannel(topic, context=ctx, metadata=t.FEATURE_METADATA)
                         for name, topic in t.FEATURES.items()}
        self.feature_box = foxglove.Channel(t.FEATURE_BOX, schema=t.FEATURE_BOX_SCHEMA, context=ctx)
        self.amplitude_scale = foxglove.Channel(t.AMPLITUDE_SCALE, schema=t.AMPLITUDE_SCALE_SCHEMA, context=ctx)
        self.range: RawImageChannel | CompressedImageChannel | None = None  # opened at the first frame
        self._range_factor: np.ndarray | float | None = None  # radial metres -> the PNG range's units (scaled_u16)
        self.calibration = CameraCalibrationChannel(t.CALIBRATION, context=ctx)
        self.nose = ImageAnnotationsChannel(t.NOSE, context=ctx)
        self.track = ImageAnnotationsChannel(t.NOSE_TRACK, context=ctx)
        self.cloud = PointCloudChannel(t.FOREGROUND, context=ctx)
        self.transform = FrameTransformChannel(t.TRANSFORM, context=ctx)
        self._rays = intrinsics.unit_rays().astype(np.float32).reshape(-1, 3)
        self._ray_z = np.ascontiguousarray(self._rays[:, 2].reshape(intrinsics.shape))
        self._fields = [PackedElementField(name=name, offset=4 * i, type=PackedElementFieldNumericType.Float32)
                        for i, name in enumerate(CLOUD_FIELDS)]
        self._fc = fc
        self.server: foxglove.WebSocketServer | None = None  # started at the first frame, after its range channel
        try:
            self._port = listen_port(fc.bind, fc.port)
        except OSError as exc:
            raise cannot_listen(fc.bind, fc.port, exc.strerror or exc) from None
        host = "127.0.0.1" if fc.bind in ("0.0.0.0", "") else fc.bind
        self.web_url = f"ws://{host}:{self._port}"

    def _start_server(self) -> None:
        """Listen (at the first frame, every channel open): the SDK advertises a channel opened while a client is
        connected a moment before it takes subscriptions to it, and the range's form is the first frame's."""
        fc = self._fc
        try:
            self.server = foxglove.start_server(name="tofd", host=fc.bind, port=self._port, context=self.context,
                                                message_backlog_size=fc.backlog_messages)
        except Exception as exc:  # the SDK raises its own error type for a port in use
            raise cannot_listen(fc.bind, self._port, exc) from None
        if not send_without_delay(self._port):
            log.warning("foxglove: no listening socket on port %d found to send without delay; a frame's messages may "
                        "reach a client tens of milliseconds late", self._port)

    def __call__(self, r: FrameResult) -> None:
        wall_s = time.time() - (time.monotonic() - r.arrival_s)  # arrival_s: this host's monotonic clock
        ns = int(wall_s * 1e9)
        stamp = Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)
        frame = r.frame
        if self.range is None:
            self._open_range(r)
        if self.server is None:
            self._start_server()
        assert self.range is not None
        # in rising importance: a slow client's full queue drops its oldest messages first
        if self.transform.has_sinks():
            self.transform.log(FrameTransform(
                timestamp=stamp, parent_frame_id=t.WORLD_FRAME, child_frame_id=t.CAMERA_FRAME,
                translation=Vector3(x=0, y=0, z=0),
                rotation=Quaternion(**dict(zip("xyzw", t.OPTICAL_IN_WORLD, strict=True)))), log_time=ns)
        box = shown_box(r.box)
        self._log_features(r, box, stamp, ns)
        if self.cloud.has_sinks():
            self.cloud.log(self._foreground(r, stamp), log_time=ns)
        if self.images[t.MASK].has_sinks():
            self.images[t.MASK].log(_png(stamp, r.mask), log_time=ns)  # black and white, 1 bit a pixel
        if self.calibration.has_sinks():
            self.calibration.log(calibration(self.intrinsics, stamp), log_time=ns)
        if self.images[t.AMPLITUDE].has_sinks() or self.amplitude_scale.has_sinks():
            amplitude, scale = amplitude_u8(frame.amplitude)
            self.amplitude_scale.log({"timestamp": _json_stamp(stamp), "units_per_level": scale}, log_time=ns)
            self.images[t.AMPLITUDE].log(CompressedImage(timestamp=stamp, frame_id=t.CAMERA_FRAME,
                                                         data=jpeg(amplitude), format="jpeg"), log_time=ns)
        if self.range.has_sinks():
            self._log_range(r, stamp, ns)
        if self.nose.has_sinks():
            self.nose.log(self._nose(r, stamp), log_time=ns)
        if self.track.has_sinks():
            self.track.log(self._track(r, stamp), log_time=ns)

    def _log_features(self, r: FrameResult, box: tuple[slice, slice], stamp: Timestamp, ns: int) -> None:
        """The subscribed feature maps over `box` (pixels.shown_box of the foreground's), then the box's place and
        each map's top value (FEATURE_BOX)."""
        wanted = {name: channel for name, channel in self.features.items() if channel.has_sinks()}
        if not wanted and not self.feature_box.has_sinks():
            return
        rows, cols = box
        tops = {}
        for name, channel in self.features.items():
            levels, tops[t.FEATURES[name]] = feature_u8(r.features[name][rows, cols])
            if name in wanted:
                channel.log(_png(stamp, levels), log_time=ns)
        self.feature_box.log({"timestamp": _json_stamp(stamp), "x": cols.start, "y": rows.start,
                              "width": cols.stop - cols.start, "height": rows.stop - rows.start, "top": tops},
                             log_time=ns)

    def _open_range(self, r: FrameResult) -> None:
        """At the first frame, the range's channel: a PNG of the source's own integers where the frame's are exact
        in them (z-depth in SensorInfo's unit: millimetre cameras; radial range codes: the SR3000), its depth
        kind and unit in the channel's metadata; else float32 radial range in metres (RawImage 32FC1)."""
        frame = r.frame
        exact, code = exact_z_units(frame, self._ray_z), radial_code_unit(frame)
        if exact is not None:
            kind, (unit, self._range_factor) = "z", exact
        elif code is not None:
            kind, unit, self._range_factor = "radial", code, 1.0 / code
        else:
            self.range = RawImageChannel(t.RANGE, context=self.context, metadata=t.range_metadata("radial", 1.0))
            return
        self.range = CompressedImageChannel(t.RANGE, context=self.context, metadata=t.range_metadata(kind, unit))

    def _log_range(self, r: FrameResult, stamp: Timestamp, ns: int) -> None:
        """Log the frame's range image as its channel carries it (_open_range)."""
        if isinstance(self.range, CompressedImageChannel) and self._range_factor is not None:
            self.range.log(_png(stamp, scaled_u16(r.frame.range_m, self._range_factor)), log_time=ns)
        elif isinstance(self.range, RawImageChannel):
            self.range.log(_image(stamp, np.ascontiguousarray(r.frame.range_m), "32FC1"), log_time=ns)

    def _foreground(self, r: FrameResult, stamp: Timestamp) -> PointCloud:
        """The foreground's points in CAMERA_FRAME with their NFFT eps0 (pixels.cloud_pixels of the mask)."""
        at = cloud_pixels(r.mask, box=r.box)
        points = np.empty(at.size, CLOUD_DTYPE)
        xyz = np.take(self._rays, at, axis=0) * np.take(r.frame.range_m.reshape(-1), at)[:, None]
        for axis, name in enumerate("xyz"):
            points[name] = xyz[:, axis]
        points["eps0"] = np.take(r.features["range_nfft_eps0"].reshape(-1), at)
        return PointCloud(timestamp=stamp, frame_id=t.CAMERA_FRAME, point_stride=CLOUD_DTYPE.itemsize,
                          fields=self._fields, data=points.tobytes())

    @staticmethod
    def _nose(r: FrameResult, stamp: Timestamp) -> ImageAnnotations:
        """The detected nose as a point: its refined tip, else the accepted pixel, as the Rerun viewer shows it
        (Foxglove's pixel origin: the top-left pixel's corner); none: empty.
        Metadata "frame_counter": the device's frame counter, as in the results file."""
        det, meta = r.detection, [KeyValuePair(key="frame_counter", value=str(r.frame.frame_counter))]
        if det is None or det.answer_px is None:
            return ImageAnnotations(timestamp=stamp, metadata=meta)
        u, v = corner_origin(det.answer_px)
        return ImageAnnotations(timestamp=stamp, metadata=meta, points=[PointsAnnotation(
            timestamp=stamp, type=PointsAnnotationType.Points, points=[Point2(x=u, y=v)], outline_color=NOSE_COLOR,
            fill_color=NOSE_COLOR, thickness=NOSE_POINT_PX)])

    def _track(self, r: FrameResult, stamp: Timestamp) -> ImageAnnotations:
        """The confirmed nose track's box and a label with its confidence; no reported track: empty. Metadata as
        _nose's."""
        box = track_box_px(r.track, self.intrinsics)
        meta = [KeyValuePair(key="frame_counter", value=str(r.frame.frame_counter))]
        if box is None or r.track is None:
            return ImageAnnotations(timestamp=stamp, metadata=meta)
        (u, v), half = box
        corners = [Point2(x=u + du * half, y=v + dv * half) for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        return ImageAnnotations(
            timestamp=stamp, metadata=meta,
            points=[PointsAnnotation(timestamp=stamp, type=PointsAnnotationType.LineLoop, points=corners,
                                     outline_color=TRACK_COLOR, thickness=1.0)],
            texts=[TextAnnotation(timestamp=stamp, position=Point2(x=u - half, y=v - half - 2),
                                  text=f"track {r.track.confidence:.2f}", font_size=10.0, text_color=TRACK_COLOR)])

    def flush(self) -> None:
        """Nothing waits: each frame is published when it comes."""

    def output_problem(self, logged: int, closing: bool) -> str | None:
        """None: a live server writes no file."""
        return None

    def close(self, timeout_s: float) -> None:
        """Stop the server (its clients are disconnected) within `timeout_s`: the SDK's stop() waits for every
        client's closing handshake, which a client that does not read never completes, so it runs on a thread
        that is left behind (the viewer process ends with os._exit, which does not wait for it)."""
        if self.server is None:
            return
        stopping = threading.Thread(target=self.server.stop, name="foxglove-stop", daemon=True)
        stopping.start()
        stopping.join(min(timeout_s, STOP_WAIT_S))
        if stopping.is_alive():
            log.warning("foxglove: a client did not close its connection in %.1f s (it stopped reading); leaving it",
                        min(timeout_s, STOP_WAIT_S))
