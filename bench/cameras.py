"""The camera geometries the benchmarks compare (the SR3000 and current cameras), and short rendered recordings of
the emulator's face motion in any of them."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from tofd.drivers.emulator.render import load_face, render_face
from tofd.drivers.emulator.scene import Motion
from tofd.drivers.frame import DeviceInfo, Frame, GroundTruth
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.replay import ReplaySource
from tofd.drivers.recording.writer import RecordingWriter
from tofd.drivers.source import FrameSource
from tofd.lab.cameras import CAMERAS as LAB_CAMERAS

CAMERAS = {label: LAB_CAMERAS[name] for label, name in (("sr3000", "sr3000"), ("320x240", "320x240"),
                                                          ("640x576", "k4a-nfov"), ("1024x1024", "1024x1024"))}
"""The geometries the benchmarks compare, labelled by their pixels in the tables (tofd.lab.cameras owns them)."""
FRAME_PERIOD_US = 33_333  # 30 fps


def write_face_clip(path: Path, intrinsics: Intrinsics, frames: int, seed: int = 1) -> Path:
    """A recording (tofd's MCAP, tofd.drivers.recording.writer) of `frames` rendered noisy frames of the emulator's face
    going from 0.35 m to 0.70 m (half a cycle of tofd.drivers.emulator.scene.Motion, its sideways drift scaled from the
    SR3000's pixels to these), with ground truth; noise seeded per frame; received every FRAME_PERIOD_US (host
    times), so a realtime replay plays it at 30 fps."""
    motion = Motion(n_poses=2 * (frames - 1), drift_px=Motion().drift_px * intrinsics.fx / Intrinsics().fx)
    face = load_face("lee_perry_smith")
    device = DeviceInfo(serial="00000000", backend="emulated", model=f"rendered {intrinsics.width}x{intrinsics.height}")
    with RecordingWriter(path, config={"rendered": {"face": face.name, "frames": frames, "seed": seed}}) as writer:
        for i in range(frames):
            r = render_face(face, motion.pose(i, intrinsics), intrinsics, np.random.default_rng((seed, i)))
            writer.write(Frame(r.range_m, r.amplitude, i, i * FRAME_PERIOD_US, i * FRAME_PERIOD_US / 1e6, 0.0,
                               intrinsics, device,
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
