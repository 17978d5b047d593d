"""Azure Kinect / Orbbec Femto recordings (.mkv, written by k4arecorder or the Orbbec K4A wrapper) as a FrameSource.

The file is Matroska (read with PyAV): a DEPTH track and an IR track (FourCC b16g: 16-bit grey, stored big-endian
by the recorder), blocks timed in microseconds from the K4A_START_OFFSET_NS tag, a calibration.json attachment
(the device's raw calibration) and tags K4A_DEPTH_MODE, K4A_DEVICE_SERIAL_NUMBER, K4A_DEPTH_FIRMWARE_VERSION.
Each capture (a DEPTH and an IR block of one timestamp) becomes a Frame:

- range_m: the z-depth (millimetres, 0 = no return) divided by the z of each pixel's ray of the depth mode's lens
  (tofd.drivers.k4a.lens), in metres; NaN for 0 and for pixels outside the lens's metric radius;
- amplitude: the IR image (active IR brightness in sensor units; passive IR in PASSIVE_IR recordings);
- timestamp_us: the device timestamp (block time + K4A_START_OFFSET_NS); the device has no frame counter, so the
  counter is the frame's index in time, round((t - t_start) / frame period) from the recording's start (block time
  0), with the period the median spacing of the first timestamps: dropped captures (at the start too) leave gaps,
  which are rejected ("damaged: ...") in their place;
- other tracks (COLOR, IMU: k4arecorder records the IMU at 1.6 kHz by default) are read past, not decoded; they
  only show how far the file goes, since they may end after the last depth capture;
- host times: the recording's creation time (Matroska DateUTC) plus the time since the first frame;
- device: the serial number tag (else the calibration's SerialId), the depth firmware tag, model "Azure Kinect"
  or "Orbbec Femto" (from the calibration's DeviceName);
- sensor (no SR3000 registers): depth in millimetres with 0 invalid, amplitude "ir" (16-bit), the frame period from
  the timestamps, and the file's K4A_* tags (depth mode, fps, firmware versions, ...) as settings.

A damaged file replays the captures the demuxer still reads and rejects the ones lost, counted from the timestamps
(and, for a file cut short, from the segment duration the recorder wrote); `stopped_reason` ("end", "truncated" or
"corrupt"), `stop_detail` and `last_good_counter` say where it stopped.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from tofd.drivers.frame import COUNTER_LIMIT, PERIOD_FRAMES, DeviceInfo, Frame, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.k4a.lens import depth_lens
from tofd.drivers.source import DriverError, FrameSource, SourceReport, StopReason

log = logging.getLogger(__name__)

MATROSKA_MAGIC = b"\x1a\x45\xdf\xa3"
"""The EBML header ID every Matroska (and WebM) file starts with."""
DEPTH_TRACK, IR_TRACK = "DEPTH", "IR"
CALIBRATION_ATTACHMENT = "calibration.json"
GREY16_FOURCC = "b16g"
LEAD_TOLERANCE = 0.25
"""A gap of n - LEAD_TOLERANCE frame periods between the file's start and its first depth capture is n lost
captures: a colour or IMU block may start the file a fraction of a period before the first depth capture."""
MAX_CALIBRATION_BYTES = 1 << 20
"""Largest calibration.json attachment read (a device's is about 10 kB)."""
MAX_LOST_FRAMES = 100_000
"""A larger gap between two captures is not counted as lost frames (a clock jump, not a drop)."""


class K4aRecordingError(DriverError):
    """An Azure Kinect / Femto recording that cannot be read: names the file, the track or tag, and why."""


@dataclass(frozen=True, slots=True)
class _Capture:
    timestamp_us: int
    depth: bytes | None
    ir: bytes | None


def _metadata(calibration: dict) -> dict:
    """The calibration's CalibrationInformation.Metadata, {} where it has none (or not as a table)."""
    info = calibration.get("CalibrationInformation")
    metadata = info.get("Metadata") if isinstance(info, dict) else None
    return metadata if isinstance(metadata, dict) else {}


def device_model(calibration: dict) -> str:
    name = str(_metadata(calibration).get("DeviceName", ""))
    return "Orbbec Femto" if "femto" in name.lower() or "orbbec" in name.lower() else "Azure Kinect"


class K4aRecordingSource(FrameSource):
    """Frames of an Azure Kinect / Femto .mkv recording, in file order (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        import av

        self.path = Path(path)
        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, OSError) as exc:
            raise K4aRecordingError(f"{self.path}: not a readable Matroska file: {exc}") from None
        try:
            self._read_header(container)
        finally:
            container.close()
        self.stopped_reason: StopReason | None = None
        self.stop_detail = ""
        self.last_good_counter: int | None = None
        self.frame_period_us: float | None = None
        """Median spacing of the first captures' timestamps (microseconds), known once iteration started."""
        first = self._captures()
        if next(first, None) is None:
            why = self.stop_detail or ("the file is damaged where its first cluster starts" if self._last_us else
                                       "the tracks hold no block")
            raise self._fail("tracks DEPTH/IR", f"nothing readable: no capture ({why})")
        first.close()
        self.stopped_reason = None

    def _fail(self, what: str, why: str) -> K4aRecordingError:
        return K4aRecordingError(f"{self.path}: {what}: {why}")

    def _read_header(self, container: Any) -> None:
        tags = {k.upper(): v for k, v in container.metadata.items()}
        tracks = {str(s.metadata.get("title", "")).upper(): s for s in container.streams.video}
        for name in (DEPTH_TRACK, IR_TRACK):
            stream = tracks.get(name)
            if stream is None:
                raise self._fail(f"track {name}", f"missing (video tracks: {', '.join(sorted(tracks)) or 'none'}); "
                                 "a depth recording has DEPTH and IR (PASSIVE_IR and colour-only ones have no depth)")
            if stream.codec_tag != GREY16_FOURCC:
                raise self._fail(f"track {name}", f"codec {stream.codec_tag!r}, expected {GREY16_FOURCC!r} "
                                 "(16-bit grey)")
        depth_tags = {k.upper(): v for k, v in tracks[DEPTH_TRACK].metadata.items()}
        mode = depth_tags.get("K4A_DEPTH_MODE") or tags.get("K4A_DEPTH_MODE")
        if not mode:
            raise self._fail("tag K4A_DEPTH_MODE", "missing: not an Azure Kinect / Femto recording")
        attachments = {s.name: s for s in container.streams if getattr(s, "type", None) == "attachment"}
        name = tags.get("K4A_CALIBRATION_FILE", CALIBRATION_ATTACHMENT)
        if name not in attachments:
            raise self._fail(f"attachment {name}", "missing: the recording has no device calibration, so its "
                             "pixels have no rays")
        raw = attachments[name].data
        if len(raw) > MAX_CALIBRATION_BYTES:
            raise self._fail(f"attachment {name}", f"{len(raw)} bytes, more than a device calibration has "
                                                   f"({MAX_CALIBRATION_BYTES})")
        try:
            lens = depth_lens(raw, mode)
            calibration = json.loads(raw)
        except ValueError as exc:
            raise self._fail(f"attachment {name}", str(exc)) from None
        self.intrinsics: Intrinsics = lens.intrinsics
        self.depth_mode = mode
        w, h = lens.intrinsics.width, lens.intrinsics.height
        for track in (DEPTH_TRACK, IR_TRACK):
            cc = tracks[track].codec_context
            if (cc.width, cc.height) != (w, h):
                raise self._fail(f"track {track}", f"{cc.width}x{cc.height} images, but depth mode {mode} makes "
                                 f"{w}x{h}")
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.float32(1e-3) / lens.intrinsics.unit_rays()[..., 2].astype(np.float32)
        scale[~lens.valid_pixels()] = np.nan
        self._mm_to_range = scale.astype(np.float32)
        """(H, W) metres of radial range per millimetre of z-depth; NaN outside the lens."""
        try:
            self._start_offset_ns = int(tags.get("K4A_START_OFFSET_NS", "0"))
        except ValueError:
            raise self._fail("tag K4A_START_OFFSET_NS", f"{tags['K4A_START_OFFSET_NS']!r} is not an integer") from None
        serial = tags.get("K4A_DEVICE_SERIAL_NUMBER") or str(_metadata(calibration).get("SerialId", ""))
        self.device = DeviceInfo(serial=serial, firmware=tags.get("K4A_DEPTH_FIRMWARE_VERSION", ""),
                                 backend="k4a-mkv", model=device_model(calibration))
        self.settings = {k: str(v) for k, v in (tags | depth_tags).items() if k.startswith("K4A_")}
        """The recording's K4A_* tags (container and DEPTH track): the device's settings as recorded."""
        self.sensor: SensorInfo | None = None
        """Signal and settings of the frames (known once iteration started: the period needs timestamps)."""
        created = tags.get("CREATION_TIME", "")
        try:
            self._wall0_s = datetime.fromisoformat(created.replace("Z", "+00:00")).timestamp() if created else 0.0
        except ValueError:
            self._wall0_s = 0.0
        self._last_us: int | None = None
        self._read_until_us: int | None = None
        """The latest block end read on any track (DEPTH, IR, COLOR, IMU): the file is whole if it reaches _last_us."""
        self._track_index = {tracks[DEPTH_TRACK].index: DEPTH_TRACK, tracks[IR_TRACK].index: IR_TRACK}
        self._image_bytes = w * h * 2

    @property
    def shape(self) -> tuple[int, int]:
        return self.intrinsics.shape

    @property
    def report(self) -> SourceReport:
        return SourceReport(self.stopped_reason, self.stop_detail, self.last_good_counter)

    def _captures(self) -> Generator[_Capture, None, None]:
        """Captures in time order: the DEPTH and IR blocks of each timestamp (None where a track has none).
        Stops (setting stopped_reason) where the demuxer cannot go on."""
        import av

        pending: dict[int, dict[str, bytes]] = {}
        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, OSError) as exc:
            raise K4aRecordingError(f"{self.path}: not a readable Matroska file: {exc}") from None
        with container:
            # Matroska's segment duration: the last block's time, which the recorder writes when it closes the file
            self._last_us = None if container.duration is None else container.duration + self._start_offset_ns // 1000
            self._read_until_us = None
            try:
                for packet in container.demux():
                    if self.closed:
                        return
                    if packet.pts is None or packet.size == 0:
                        continue
                    t_us = int(round(float(packet.pts * packet.time_base) * 1e6)) + self._start_offset_ns // 1000
                    end_us = t_us + int(round(float((packet.duration or 0) * packet.time_base) * 1e6))
                    self._read_until_us = max(end_us, self._read_until_us or end_us)  # an IMU block spans samples
                    if packet.stream.index not in self._track_index:  # colour, IMU: only how far the file goes
                        continue
                    for done in sorted(t for t in pending if t < t_us):
                        yield _Capture(done, pending[done].get(DEPTH_TRACK), pending[done].pop(IR_TRACK, None))
                        del pending[done]
                    track = self._track_index[packet.stream.index]
                    pending.setdefault(t_us, {})[track] = bytes(packet)
            except (av.FFmpegError, OSError) as exc:
                self.stopped_reason, self.stop_detail = "corrupt", f"{type(exc).__name__}: {exc}"
            for done in sorted(pending):
                yield _Capture(done, pending[done].get(DEPTH_TRACK), pending[done].get(IR_TRACK))
        if self.stopped_reason is None:
            self.stopped_reason = "end"

    def _problem(self, capture: _Capture) -> str | None:
        for track, data in ((DEPTH_TRACK, capture.depth), (IR_TRACK, capture.ir)):
            if data is None:
                return f"damaged: no {track} image at {capture.timestamp_us} us"
            if len(data) != self._image_bytes:
                return (f"damaged: {track} image at {capture.timestamp_us} us has {len(data)} bytes, expected "
                        f"{self._image_bytes}")
        return None

    def _frame(self, capture: _Capture, counter: int, t0_us: int) -> Frame:
        assert capture.depth is not None and capture.ir is not None
        h, w = self.shape
        depth = np.frombuffer(capture.depth, ">u2").reshape(h, w)
        range_m = depth.astype(np.float32) * self._mm_to_range
        range_m[depth == 0] = np.nan
        since_s = (capture.timestamp_us - t0_us) / 1e6
        return Frame(range_m=range_m, amplitude=np.frombuffer(capture.ir, ">u2").reshape(h, w).astype(np.float32),
                     frame_counter=counter, timestamp_us=capture.timestamp_us,
                     host_monotonic_s=capture.timestamp_us / 1e6, host_wall_s=self._wall0_s + since_s,
                     intrinsics=self.intrinsics, device=self.device, sensor=self.sensor)

    def __iter__(self) -> Iterator[Frame]:
        captures = self._captures()
        head = [c for _, c in zip(range(PERIOD_FRAMES), captures, strict=False)]
        if not head:
            return
        steps = np.diff([c.timestamp_us for c in head])
        self.frame_period_us = float(np.median(steps)) if len(steps) and np.median(steps) > 0 else None
        self.sensor = SensorInfo(depth_unit_m=1e-3, amplitude="ir", invalid_value=0, amplitude_full_scale=65535.0,
                                 frame_period_s=None if self.frame_period_us is None else self.frame_period_us / 1e6,
                                 settings=self.settings)
        t0 = self._start_offset_ns // 1000  # block time 0: captures lost before the first readable one are counted
        last: int | None = -1
        if head[0].timestamp_us < t0 or self.frame_period_us is None:
            t0, last = head[0].timestamp_us, None
        else:  # whole periods before the first depth capture; a colour or IMU block may lead it by less than one
            lost_before = int((head[0].timestamp_us - t0) / self.frame_period_us + LEAD_TOLERANCE)
            t0 = head[0].timestamp_us - round(lost_before * self.frame_period_us)
        for capture in (*head, *captures):
            counter = 0 if self.frame_period_us is None else round((capture.timestamp_us - t0) / self.frame_period_us)
            if last is not None and counter <= last:
                counter = last + 1  # jitter: keep counters increasing
            if counter >= COUNTER_LIMIT:
                self.stopped_reason, self.stop_detail = "end", f"frame counter reached 2**32 at {capture.timestamp_us}"
                break
            if last is not None and 1 < counter - last <= MAX_LOST_FRAMES:
                period = self.frame_period_us or 0
                self.reject(last + 1, f"damaged: no capture from {t0 + round((last + 1) * period)} us to "
                                      f"{t0 + round((counter - 1) * period)} us (between {last} and {counter})",
                            counter - last - 1)
            last = counter
            problem = self._problem(capture)
            if problem is not None:
                self.reject(counter, problem)
                continue
            self.last_good_counter = counter
            yield self._frame(capture, counter, t0)
        if self.closed:
            return
        self._reject_tail(last, t0)
        if self.stopped_reason not in (None, "end"):
            self.counters["corrupt_tail"] += 1
            log.warning("%s: replayed the readable prefix (last frame counter %s); %s: %s", self.path,
                        self.last_good_counter, self.stopped_reason, self.stop_detail)

    def _reject_tail(self, last: int | None, t0_us: int) -> None:
        """When the segment duration says the recording went on past the last block read on any track (a truncated
        or damaged end), reject the captures lost after the last one read and mark the recording truncated. (The
        colour and IMU tracks may go on past the last depth capture of a whole file.)"""
        if self._last_us is None or last is None or not self.frame_period_us:
            return
        if self._read_until_us is not None and self._read_until_us >= self._last_us:
            return
        final = round((self._last_us - t0_us) / self.frame_period_us)
        if not last < final <= last + MAX_LOST_FRAMES:
            return
        if self.stopped_reason in (None, "end"):
            self.stopped_reason = "truncated"
            self.stop_detail = f"the file ends at {t0_us + round(last * self.frame_period_us)} us, its duration at " \
                               f"{self._last_us} us"
        self.reject(last + 1, f"damaged: {self.stopped_reason} file ({self.stop_detail})", final - last)

    @property
    def fps(self) -> float | None:
        """Frame rate from the timestamps (known once iteration started)."""
        return None if not self.frame_period_us else 1e6 / self.frame_period_us
