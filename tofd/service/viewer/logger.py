"""Logs one FrameResult to a Rerun RecordingStream (entity tree in blueprint.py); runs on the sink thread.

Per frame (~0.6 MB): z-depth under the Pinhole (what Rerun's DepthImage means, so the 3-D projection is right),
the radial range outside it, amplitude (uint16), mask, four feature maps, the foreground cloud (~3000 points),
the detected nose in 2-D and 3-D, beside it the confirmed nose track (a box of TRACK_BOX_M about its pixel,
labelled with its confidence, and its 3-D point) and the track's confidence, one scalar per stage timing.
Timelines: `frame` (device frame counter) and `device_time` (device clock). set_time is thread-local in Rerun, so it
is called here, on the logging thread.
"""

from __future__ import annotations

import time
from functools import cache

import numpy as np
import rerun as rr

from drivers.intrinsics import Intrinsics
from tofd.algorithm.tracking import TrackState
from tofd.service.pipeline.results import FrameResult, track_px
from tofd.service.pipeline.stats import TIMED_STAGES
from tofd.service.viewer import blueprint as bp

NOSE_COLOR = (255, 0, 255)
TRACK_COLOR = (0, 200, 255)
TRACK_BOX_M = 0.03  # metres: side of the track's box in the image, at the track's depth (a nose's size)


@cache
def _viridis() -> np.ndarray:
    """(256, 3) uint8 lookup table of the viridis colour map."""
    from matplotlib import colormaps

    return (colormaps["viridis"](np.linspace(0, 1, 256))[:, :3] * 255).astype(np.uint8)


def colour_by(values: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 viridis colours of log10(values), scaled to their 2nd-98th percentile."""
    lut = _viridis()
    logv = np.log10(np.maximum(values, 1e-30))
    finite = np.isfinite(values)
    if not finite.any():
        return np.zeros((len(values), 3), np.uint8)
    lo, hi = np.percentile(logv[finite], [2, 98])
    idx = np.clip((logv - lo) / max(hi - lo, 1e-12) * 255, 0, 255)
    return lut[np.where(finite, idx, 0).astype(np.intp)]


def z_depth(radial_m: np.ndarray, ray_z: np.ndarray) -> np.ndarray:
    """(H, W) float32 planar depth (metres along the optical axis) of a radial range map: range * ray_z."""
    return (radial_m * ray_z).astype(np.float32)


def amplitude_u16(amplitude: np.ndarray) -> np.ndarray:
    """(H, W) uint16 amplitude (the sensor's integer units), rounded and clipped; NaN becomes 0."""
    return np.clip(np.rint(np.nan_to_num(amplitude, nan=0.0)), 0, 65535).astype(np.uint16)


class RerunLogger:
    """Callable sink: logs static entities once at construction, then every FrameResult it is given."""

    def __init__(self, rec: rr.RecordingStream, intrinsics: Intrinsics, point_cloud: bool = True):
        self.rec, self.point_cloud = rec, point_cloud
        self._rays = intrinsics.unit_rays().astype(np.float32)
        self._ray_z = np.ascontiguousarray(self._rays[..., 2])  # z-depth = radial range * cos(angle to the axis)
        rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)
        rec.log(bp.CAMERA, rr.Pinhole(focal_length=[intrinsics.fx, intrinsics.fy],
                                      principal_point=[intrinsics.cx + 0.5, intrinsics.cy + 0.5],
                                      width=intrinsics.width, height=intrinsics.height), static=True)
        rec.log(bp.MASK, rr.AnnotationContext([(0, "background", (0, 0, 0)), (1, "foreground", (230, 60, 40))]),
                static=True)
        for stage in TIMED_STAGES:
            rec.log(f"{bp.TIMINGS}/{stage}", rr.SeriesLines(names=f"{stage} [ms]"), static=True)

    def __call__(self, r: FrameResult) -> None:
        t0 = time.perf_counter()
        rec, frame = self.rec, r.frame
        rec.set_time("frame", sequence=frame.frame_counter)
        rec.set_time("device_time", duration=frame.timestamp_us * 1e-6)
        if r.gap_before:
            rec.log(bp.EVENTS, rr.TextLog(f"{r.gap_before} before frame {frame.frame_counter}",
                                          level=rr.TextLogLevel.WARN))
        radial = np.nan_to_num(frame.range_m, nan=0.0)
        rec.log(bp.RANGE, rr.DepthImage(z_depth(radial, self._ray_z), meter=1.0, colormap="turbo"))
        rec.log(bp.RANGE_RADIAL, rr.DepthImage(radial, meter=1.0, colormap="turbo"))
        rec.log(bp.AMPLITUDE, rr.Image(amplitude_u16(frame.amplitude)))
        rec.log(bp.MASK, rr.SegmentationImage(r.mask.view(np.uint8)))
        for name, path in bp.FEATURES.items():
            # a DepthImage is Rerun's colour-mapped scalar image; these are eccentricities, NaN (shown as 0)
            # outside the foreground, not depths.
            rec.log(path, rr.DepthImage(np.nan_to_num(r.features[name], nan=0.0), colormap="viridis"))
        if self.point_cloud:
            eps0 = r.features["range_nfft_eps0"][r.mask]
            points = self._rays[r.mask] * frame.range_m[r.mask][:, None]
            rec.log(bp.FOREGROUND, rr.Points3D(points, colors=colour_by(eps0), radii=0.002))
        det = r.detection
        if det is not None and det.nose_px is not None:
            rec.log(bp.NOSE_2D, rr.Points2D([det.nose_px], radii=3, colors=[NOSE_COLOR], labels="nose"))
            rec.log(bp.NOSE_3D, rr.Points3D([det.nose_xyz_m], radii=0.01, colors=[NOSE_COLOR]))
        elif det is not None:
            rec.log(bp.NOSE_2D, rr.Clear(recursive=False))
            rec.log(bp.NOSE_3D, rr.Clear(recursive=False))
        if r.track is not None:
            self._log_track(r.track, frame.intrinsics)
        for stage, ms in r.timings_ms.items():
            rec.log(f"{bp.TIMINGS}/{stage}", rr.Scalars(ms))
        rec.log(f"{bp.TIMINGS}/logging", rr.Scalars((time.perf_counter() - t0) * 1e3))
        rec.log(f"{bp.TIMINGS}/latency", rr.Scalars((time.monotonic() - r.arrival_s) * 1e3))

    def _log_track(self, track: TrackState, intrinsics: Intrinsics) -> None:
        """The confirmed track's box and point (cleared while there is none) and its confidence."""
        rec, px = self.rec, track_px(track, intrinsics)
        if px is not None and track.nose_xyz_m is not None:
            side = TRACK_BOX_M * intrinsics.fx / track.nose_xyz_m[2]
            rec.log(bp.TRACK_2D, rr.Boxes2D(centers=[px], sizes=[[side, side]], colors=[TRACK_COLOR],
                                            labels=f"track {track.confidence:.2f}"))
            rec.log(bp.TRACK_3D, rr.Points3D([track.nose_xyz_m], radii=0.006, colors=[TRACK_COLOR]))
        else:
            rec.log(bp.TRACK_2D, rr.Clear(recursive=False))
            rec.log(bp.TRACK_3D, rr.Clear(recursive=False))
        rec.log(bp.TRACK_CONFIDENCE, rr.Scalars(track.confidence))
