"""Frame sources for the pipeline tests: rendered faces (drivers.render), optionally paced, with injected gaps."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np

from drivers.camera import Intrinsics
from drivers.frame import DeviceInfo, Frame, GroundTruth
from drivers.render import Pose, load_face, render_face
from drivers.source import FrameSource


def rendered_frames(n_distinct: int = 8, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, tuple[float, float]]]:
    """`n_distinct` noisy renderings of a face moving from 0.35 to 0.70 m: (range_m, amplitude, nose_px)."""
    rng, face = np.random.default_rng(seed), load_face("lee_perry_smith")
    out = []
    for d in np.linspace(0.35, 0.70, n_distinct):
        r = render_face(face, Pose(distance_m=float(d), yaw_deg=10.0 * np.sin(d * 20)), rng=rng)
        out.append((r.range_m, r.amplitude, r.nose_px))
    return out


class RenderedSource(FrameSource):
    """`n_frames` frames cycling through pre-rendered images; `fps` > 0 paces them like a camera.

    `skip_counters`: frame counters never emitted (a device-side counter gap).
    """

    def __init__(self, n_frames: int, fps: float = 0.0, skip_counters: tuple[int, ...] = (), n_distinct: int = 8):
        super().__init__()
        self.n_frames, self.fps, self.skip = n_frames, fps, set(skip_counters)
        self.images = rendered_frames(n_distinct)
        self.intrinsics = Intrinsics()
        self.emitted: list[int] = []

    def __iter__(self) -> Iterator[Frame]:
        t0 = time.monotonic()
        for counter in range(self.n_frames):
            if self.closed:
                return
            if self.fps > 0:
                time.sleep(max(0.0, t0 + counter / self.fps - time.monotonic()))
            if counter in self.skip:
                continue
            range_m, amplitude, nose = self.images[counter % len(self.images)]
            self.emitted.append(counter)
            yield Frame(range_m.copy(), amplitude.copy(), counter, timestamp_us=counter * 33_333,
                        host_monotonic_s=time.monotonic(), host_wall_s=time.time(), intrinsics=self.intrinsics,
                        device=DeviceInfo("0000BEEF", backend="emulated"), ground_truth=GroundTruth(nose))
