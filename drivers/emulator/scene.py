"""What the emulated camera sees: a rendered face on a periodic path, as protocol payloads with ground truth."""

from __future__ import annotations

import math
import threading
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tofd.drivers import sr3000
from tofd.drivers.emulator import render, render_cache
from tofd.drivers.emulator.render import Pose, SensorModel, load_face, render_face
from tofd.drivers.frame import GroundTruth
from tofd.drivers.intrinsics import Intrinsics


@dataclass(frozen=True, slots=True)
class Motion:
    """A closed path of head poses, sampled at `n_poses` frames (pose = frame_counter mod n_poses).

    Over one cycle the nose tip goes from near_m to far_m and back (cosine), the head turns
    ±yaw_deg twice and nods ±pitch_deg once, and the nose drifts ±drift_px sideways in the image.
    """

    n_poses: int = 240  # 8 s per cycle at 30 fps
    near_m: float = 0.35
    far_m: float = 0.70
    yaw_deg: float = 25.0
    pitch_deg: float = 10.0
    drift_px: float = 12.0

    def pose(self, index: int, intrinsics: Intrinsics) -> Pose:
        phase = 2 * math.pi * (index % self.n_poses) / self.n_poses
        mid, half = (self.near_m + self.far_m) / 2, (self.far_m - self.near_m) / 2
        return Pose(distance_m=mid - half * math.cos(phase), yaw_deg=self.yaw_deg * math.sin(2 * phase),
                    pitch_deg=self.pitch_deg * math.sin(phase),
                    nose_px=(intrinsics.cx + self.drift_px * math.sin(phase), intrinsics.cy - 4.0))


class FaceScene:
    """Rendered face frames; each pose is rendered once (on first use, or all at once by prerender()).

    Payload encoding: distance per tofd.drivers.sr3000.range_m_to_raw (NaN or beyond the non-ambiguity range ->
    0xFFFF) for the modulation frequency of the frame; amplitude = renderer units (SensorModel.gain is the
    amplitude of an albedo-1 surface at 1 m), rounded and clipped to 0..65535. Noise is seeded per pose,
    so a frame counter always gives the same image.
    """

    def __init__(self, face: str = "lee_perry_smith", motion: Motion | None = None,
                 intrinsics: Intrinsics | None = None, model: SensorModel | None = None, seed: int = 0) -> None:
        self.mesh = load_face(face)
        self.motion = motion or Motion()
        self.intrinsics = intrinsics or Intrinsics()
        if self.intrinsics.shape != (sr3000.HEIGHT, sr3000.WIDTH):
            raise ValueError(f"intrinsics: shape {self.intrinsics.shape}, expected the SR3000's "
                             f"{(sr3000.HEIGHT, sr3000.WIDTH)}")
        self.model = model
        self.seed = seed
        self._poses: dict[int, tuple[np.ndarray, np.ndarray, GroundTruth]] = {}
        self._payloads: dict[tuple[int, int], tuple[bytes, int]] = {}

    def _pose(self, frame_counter: int) -> tuple[np.ndarray, np.ndarray, GroundTruth]:
        """(range_m float32, amplitude uint16, ground truth) of the pose of this frame, rendered once."""
        index = frame_counter % self.motion.n_poses
        if index not in self._poses:
            rng = np.random.default_rng([self.seed, index])
            r = render_face(self.mesh, self.motion.pose(index, self.intrinsics), self.intrinsics, rng, self.model)
            amplitude = np.clip(np.rint(r.amplitude), 0, 65535).astype("<u2")
            truth = GroundTruth(nose_px=r.nose_px, visible=r.nose_visible, nose_xyz_m=r.nose_xyz_m)
            self._poses[index] = (r.range_m, amplitude, truth)
        return self._poses[index]

    @property
    def rendered(self) -> bool:
        """Whether every pose of the cycle is rendered (streaming then never waits for the renderer)."""
        return len(self._poses) == self.motion.n_poses

    def prerender(self) -> None:
        """Render every pose of the cycle now (about 50 ms each, or read them from the render cache), so streaming
        never waits for the renderer."""
        key = self._cache_key()
        cached = render_cache.load(key, self.motion.n_poses)
        if cached is not None:
            self._poses.update(cached)
            return
        for index in range(self.motion.n_poses):
            self._pose(index)
        render_cache.store(key, self._poses)

    def _cache_key(self) -> str:
        """The render cache's name for this scene: the mesh, motion, intrinsics, sensor model, seed and the source
        of the renderer and of this module (a changed renderer never reads old images)."""
        sources = (Path(render.__file__).read_bytes(), Path(__file__).read_bytes())
        return render_cache.entry_key([self.mesh.vertices.tobytes(), self.mesh.faces.tobytes(),
                                       str(self.mesh.nose).encode(), repr(self.motion).encode(),
                                       repr(self.intrinsics).encode(), repr(self.model).encode(),
                                       str(self.seed).encode(), *sources])

    def prerender_in_background(self) -> threading.Thread:
        """Render the cycle on a daemon thread that ends when done, staying ahead of a 30 fps stream (a pose
        asked for before it is ready is rendered on the spot; rendering twice gives the same image)."""
        thread = threading.Thread(target=self.prerender, name="face-scene-prerender", daemon=True)
        thread.start()
        return thread

    def payload(self, frame_counter: int, freq_khz: int) -> tuple[bytes, int]:
        """(payload bytes, CRC-32) of the frame at this counter and modulation frequency."""
        key = (frame_counter % self.motion.n_poses, freq_khz)
        if key not in self._payloads:
            range_m, amplitude, _ = self._pose(frame_counter)
            data = np.stack([sr3000.range_m_to_raw(range_m, freq_khz), amplitude]).tobytes()
            self._payloads[key] = (data, zlib.crc32(data))
        return self._payloads[key]

    def ground_truth(self, frame_counter: int) -> GroundTruth:
        """The nose tip of the frame with this counter."""
        return self._pose(frame_counter)[2]
