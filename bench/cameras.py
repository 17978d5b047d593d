"""The camera geometries the benchmarks compare (the SR3000 and current cameras), and short rendered recordings of
the emulator's face motion in any of them."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from tofd.drivers.emulator.render import SensorModel, load_face, range_noise_sigma, render_face
from tofd.drivers.emulator.scene import Motion
from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth, SensorInfo
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.replay import ReplaySource
from tofd.drivers.recording.writer import RecordingWriter
from tofd.drivers.source import FrameSource
from tofd.lab.cameras import CAMERAS as LAB_CAMERAS
from tofd.lab.conditions import CONDITIONS

CAMERAS = {label: LAB_CAMERAS[name] for label, name in (("sr3000", "sr3000"), ("320x240", "320x240"),
                                                          ("640x576", "k4a-nfov"), ("1024x1024", "1024x1024"))}
"""The geometries the benchmarks compare, labelled by their pixels in the tables (tofd.lab.cameras owns them)."""
FRAME_PERIOD_US = 33_333  # 30 fps

K4A_RANDOM_ERROR_M = 0.017
"""The Azure Kinect's specified random depth error (standard deviation) over its operating range (NFOV unbinned
0.5-3.86 m, 15-95 % reflectivity at 850 nm): the hardware specification. Pixels whose signal is too low for
that are invalidated by its depth engine (reported as 0), not delivered noisier."""
SENSOR_MODELS = {**CONDITIONS, "k4a_spec_noise": SensorModel(max_range_noise_m=K4A_RANDOM_ERROR_M)}
"""Sensor models a clip is rendered with: tofd.lab.conditions' and a millimetre camera's within its specification
(the training sensor's amplitude-tied noise, at most K4A_RANDOM_ERROR_M: the SR3000-like model gives the wall of the
scene, 1.6 m away at albedo 0.35 and inside the Azure Kinect's operating range, several times that)."""


def range_noise_mm(intrinsics: Intrinsics, model: SensorModel) -> dict[str, float]:
    """The range noise (standard deviation, mm) `model` puts on the first pose of write_face_clip's motion in this
    geometry: its median and 95th percentile over the pixels, and the share of pixels above K4A_RANDOM_ERROR_M."""
    pose = Motion(drift_px=Motion().drift_px * intrinsics.fx / Intrinsics().fx).pose(0, intrinsics)
    sigma = range_noise_sigma(render_face(load_face("lee_perry_smith"), pose, intrinsics, None, model).amplitude,
                              model)
    return {"median": round(float(np.median(sigma)) * 1e3, 1), "p95": round(float(np.percentile(sigma, 95)) * 1e3, 1),
            "share_above_k4a_spec": round(float(np.mean(sigma > K4A_RANDOM_ERROR_M)), 3)}


def as_millimetre_camera(range_m: np.ndarray, amplitude: np.ndarray, intrinsics: Intrinsics
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(range_m, amplitude) as a camera measuring z-depth in whole millimetres (Azure Kinect, Orbbec, RealSense)
    delivers them through its tofd driver: the z-depth rounded to millimetres (0 = no return -> NaN) and turned
    into radial range the way the Azure Kinect driver does, the amplitude rounded to whole units (0-65535)."""
    ray_z = intrinsics.unit_rays()[..., 2].astype(np.float32)
    z_mm = np.rint(np.nan_to_num(range_m * ray_z, nan=0.0) * 1000)
    radial = np.where(z_mm > 0, z_mm * (np.float32(1e-3) / ray_z), np.nan).astype(np.float32)
    return radial, np.clip(np.rint(np.nan_to_num(amplitude, nan=0.0)), 0, 65535).astype(np.float32)


def write_face_clip(path: Path, intrinsics: Intrinsics, frames: int, seed: int = 1, millimetres: bool = False,
                    model: SensorModel | None = None) -> Path:
    """A recording (tofd's MCAP, tofd.drivers.recording.writer) of `frames` rendered noisy frames of the emulator's face
    going from 0.35 m to 0.70 m (half a cycle of tofd.drivers.emulator.scene.Motion, its sideways drift scaled from the
    SR3000's pixels to these), with ground truth; noise seeded per frame; received every FRAME_PERIOD_US (host
    times), so a realtime replay plays it at 30 fps. millimetres: as a millimetre camera delivers them
    (as_millimetre_camera, with SensorInfo saying so), else float planes as rendered; `model`: the sensor's
    effects (default: the emulator's)."""
    motion = Motion(n_poses=2 * (frames - 1), drift_px=Motion().drift_px * intrinsics.fx / Intrinsics().fx)
    face = load_face("lee_perry_smith")
    device = DeviceInfo(serial="00000000", backend="emulated", model=f"rendered {intrinsics.width}x{intrinsics.height}")
    sensor = SensorInfo(depth_unit_m=1e-3, amplitude="ir", amplitude_full_scale=65535) if millimetres else None
    with RecordingWriter(path, config={"rendered": {"face": face.name, "frames": frames, "seed": seed}}) as writer:
        for i in range(frames):
            r = render_face(face, motion.pose(i, intrinsics), intrinsics, np.random.default_rng((seed, i)), model)
            range_m, amplitude = (as_millimetre_camera(r.range_m, r.amplitude, intrinsics) if millimetres
                                  else (r.range_m, r.amplitude))
            writer.write(Frame(range_m, amplitude, i, i * FRAME_PERIOD_US, i * FRAME_PERIOD_US / 1e6, 0.0,
                               intrinsics, device, sensor=sensor,
                               ground_truth=GroundTruth(nose_px=r.nose_px, visible=r.nose_visible,
                                                        nose_xyz_m=r.nose_xyz_m)))
    return path


class MemoryCamera(FrameSource):
    """A clip's frames read into memory once and handed over in real time (FRAME_PERIOD_US apart, looped, counters
    and device times running on) as a camera's driver hands over raw frames: a new buffer per frame, no file read
    or decompressed in the capture thread."""

    def __init__(self, clip: Path):
        super().__init__()
        with ReplaySource(clip) as source:
            self.frames = list(source)

    def __iter__(self) -> Iterator[Frame]:
        t0, i = time.monotonic(), 0
        while not self.closed:
            wait = t0 + i * FRAME_PERIOD_US * 1e-6 - time.monotonic()
            if wait > 0 and self._closed.wait(wait):
                return
            f = self.frames[i % len(self.frames)]
            yield replace(f, range_m=f.range_m.copy(), amplitude=f.amplitude.copy(), frame_counter=i,
                          timestamp_us=i * FRAME_PERIOD_US, host_monotonic_s=time.monotonic(), host_wall_s=time.time())
            i += 1
