"""Labelled SR3000-like face frames for training and evaluating the nose detector (tofd.drivers.emulator.render).

Subjects are the two bundled meshes plus identity variations of them: anisotropic scaling about the nose tip
and smooth local displacements (Gaussian radial-basis bumps, metres) around landmark vertices -- nose tip,
cheeks, chin -- found on each mesh by their position relative to the nose tip; and face shapes drawn over the
adult range of nose protrusion, width and height, bridge, cheeks, brow and chin (tofd.lab.face_shapes), six on
each base mesh, each with its own seed (`<mesh>_s<k>`); and 22 heads of the ICT Face Model, a morphable
model of scanned people (tofd.lab.morphable_faces, `ict_<k>`): whole heads of their own, not variations.

Default split (the paper's experiment): train on three subjects at 0.60 m, test on a fourth subject at
0.35-0.70 m; yaw uniform in +-30 deg, pitch in +-15 deg, the nose tip a few pixels off the image centre;
range noise and flying pixels from the renderer's sensor model. Other subjects can take either role
(`tofd train --train-subjects`, `tofd evaluate --test-subjects`). This module owns the identity lists: the
drawn shapes and the model's heads split into SHAPE_TRAIN_SUBJECTS (training), SHAPE_TUNE_SUBJECTS (choosing
settings) and HOLDOUT_SUBJECTS (unseen-face checks: never trained or tuned on; ICT_HOLDOUT_SUBJECTS the heads);
OLD_HOLDOUT_SUBJECTS, a larger and a smaller nose on the training meshes, are the earlier unseen-face checks, kept
for comparison.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tofd.drivers.emulator.render import FaceMesh, Pose, SensorModel, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.dataset import Dataset
from tofd.lab.face_shapes import deform, draw_shape
from tofd.lab.morphable_faces import MESH as ICT_MESH
from tofd.lab.morphable_faces import draw_identity

LANDMARK_OFFSETS_M: dict[str, tuple[float, float]] = {
    "nose": (0.0, 0.0),
    "chin": (0.0, -0.065),
    "cheek_left": (-0.045, -0.01),
    "cheek_right": (0.045, -0.01),
}
"""Landmark -> (x, y) offset from the nose tip in the head frame (x right, y up), metres."""


@dataclass(frozen=True, slots=True)
class Bump:
    """A smooth displacement of the surface around a landmark: shift_m * exp(-d^2 / (2 sigma_m^2))."""

    landmark: str
    shift_m: tuple[float, float, float]  # head frame (x right, y up, z out of the face), metres
    sigma_m: float


@dataclass(frozen=True, slots=True)
class Subject:
    """An identity: a base mesh, an anisotropic scale about the nose tip, and local bumps; or a base mesh deformed
    to the face shape drawn with `shape_seed` (tofd.lab.face_shapes); or the head of the morphable model drawn with
    `identity_seed` (tofd.lab.morphable_faces; mesh: its MESH)."""

    name: str
    mesh: str  # tofd.drivers.emulator.render.FACE_NAMES
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    bumps: tuple[Bump, ...] = ()
    shape_seed: int | None = None
    identity_seed: int | None = None


SUBJECTS: dict[str, Subject] = {s.name: s for s in (
    Subject("lps", "lee_perry_smith"),
    Subject("mp", "mediapipe_canonical"),
    Subject("mp_broad", "mediapipe_canonical", (1.08, 0.95, 1.0), (
        Bump("nose", (0.0, 0.0, 0.004), 0.012),
        Bump("cheek_left", (0.0, 0.0, 0.005), 0.02), Bump("cheek_right", (0.0, 0.0, 0.005), 0.02),
        Bump("chin", (0.0, 0.002, -0.004), 0.02))),
    Subject("lps_long", "lee_perry_smith", (0.94, 1.06, 1.05), (
        Bump("nose", (0.0, -0.002, 0.003), 0.012),
        Bump("cheek_left", (0.0, 0.0, -0.003), 0.02), Bump("cheek_right", (0.0, 0.0, -0.003), 0.02),
        Bump("chin", (0.0, -0.004, 0.006), 0.02))),
    Subject("mp_chin", "mediapipe_canonical", (0.97, 1.03, 1.0), (  # forward chin: 14 mm behind the nose tip
        Bump("chin", (0.0, -0.003, 0.010), 0.018),)),
    Subject("lps_flat", "lee_perry_smith", (1.03, 0.98, 0.95), (  # flatter nose, fuller cheeks
        Bump("nose", (0.0, 0.0, -0.004), 0.012),
        Bump("cheek_left", (0.0, 0.0, 0.003), 0.02), Bump("cheek_right", (0.0, 0.0, 0.003), 0.02))),
    Subject("mp_bignose", "mediapipe_canonical", (0.93, 1.04, 1.08), (  # narrow face, nose 6 mm further out
        Bump("nose", (0.0, -0.002, 0.006), 0.010), Bump("chin", (0.0, 0.0, -0.004), 0.02))),
    Subject("lps_smallnose", "lee_perry_smith", (1.02, 0.97, 0.92), (  # nose 6 mm shallower, fuller cheeks
        Bump("nose", (0.0, 0.001, -0.006), 0.010),
        Bump("cheek_left", (0.0, 0.0, 0.005), 0.022), Bump("cheek_right", (0.0, 0.0, 0.005), 0.022))),
    *(Subject(f"{short}_s{k}", mesh, shape_seed=seed + k) for short, mesh, seed in (
        ("lps", "lee_perry_smith", 4600), ("mp", "mediapipe_canonical", 4700)) for k in range(1, 7)),
    *(Subject(f"ict_{k}", ICT_MESH, identity_seed=5000 + k) for k in range(1, 23)),
)}

TRAIN_SUBJECTS = ("lps", "mp", "mp_broad")
CV_SUBJECTS = (*TRAIN_SUBJECTS, "mp_chin", "lps_flat")  # bench/tune_detector.py: never the test subject
TEST_SUBJECTS = ("lps_long",)
OLD_HOLDOUT_SUBJECTS = ("mp_bignose", "lps_smallnose")  # scaled/bumped copies of training meshes, never trained on
ICT_TRAIN_SUBJECTS = tuple(f"ict_{k}" for k in range(1, 9))  # heads of the morphable model for training
SHAPE_TRAIN_SUBJECTS = ("lps_s1", "lps_s2", "lps_s3", "mp_s1", "mp_s2", "mp_s3", *ICT_TRAIN_SUBJECTS)
ICT_TUNE_SUBJECTS = ("ict_9", "ict_10", *(f"ict_{k}" for k in range(17, 23)))
SHAPE_TUNE_SUBJECTS = ("lps_s4", "mp_s4", *ICT_TUNE_SUBJECTS)  # for choosing settings (cross-validation, thresholds)
ICT_HOLDOUT_SUBJECTS = tuple(f"ict_{k}" for k in range(11, 17))  # unseen heads: never trained or tuned on
HOLDOUT_SUBJECTS = (*ICT_HOLDOUT_SUBJECTS, "lps_s5", "lps_s6", "mp_s5", "mp_s6")  # never trained or tuned on
TRAIN_DISTANCES_M = (0.60,)
TEST_DISTANCES_M = (0.35, 0.40, 0.45, 0.50, 0.55, 0.60, 0.65, 0.70)
YAW_DEG, PITCH_DEG = 30.0, 15.0  # poses uniform in +-these
CENTRE_JITTER_PX = 8.0  # nose tip placed uniformly within +-this of the principal point


def landmark_vertices(mesh: FaceMesh) -> dict[str, int]:
    """Vertex index per landmark: the front-most vertex within 8 mm (x, y) of its offset from the nose tip."""
    v, tip = mesh.vertices, mesh.vertices[mesh.nose]
    out = {}
    for name, (dx, dy) in LANDMARK_OFFSETS_M.items():
        d2 = (v[:, 0] - tip[0] - dx) ** 2 + (v[:, 1] - tip[1] - dy) ** 2
        near = np.flatnonzero(d2 < 0.008**2)
        out[name] = int(near[np.argmax(v[near, 2])]) if len(near) else int(np.argmin(d2))
    return out


def make_subject(subject: Subject) -> FaceMesh:
    """The subject's mesh: base mesh (deformed to its drawn face shape, if any) scaled about its nose tip, then
    displaced by its bumps (vectorised)."""
    base = load_face(subject.mesh) if subject.identity_seed is None else draw_identity(subject.identity_seed,
                                                                                       subject.name)
    if subject.shape_seed is not None:
        base = deform(base, draw_shape(subject.shape_seed), subject.name)
    marks = landmark_vertices(base)
    tip = base.vertices[base.nose]
    v = (base.vertices - tip) * np.asarray(subject.scale) + tip
    if subject.bumps:
        centres = np.array([v[marks[b.landmark]] for b in subject.bumps])  # (B, 3)
        shifts = np.array([b.shift_m for b in subject.bumps])  # (B, 3)
        sigmas = np.array([b.sigma_m for b in subject.bumps])  # (B,)
        d2 = ((v[:, None, :] - centres[None]) ** 2).sum(-1)  # (N, B)
        v = v + np.exp(-d2 / (2 * sigmas**2)) @ shifts
    return base.with_vertices(v, name=subject.name)


def _split(split: str) -> tuple[tuple[str, ...], tuple[float, ...]]:
    if split == "train":
        return TRAIN_SUBJECTS, TRAIN_DISTANCES_M
    if split == "test":
        return TEST_SUBJECTS, TEST_DISTANCES_M
    raise ValueError(f"split must be 'train' or 'test', got {split!r}")


def generate(
    split: str = "train",
    frames: int = 120,
    seed: int = 0,
    intrinsics: Intrinsics | None = None,
    progress: Callable[[int, int], None] | None = None,
    subjects: tuple[str, ...] | None = None,
) -> Dataset:
    """Render `frames` labelled frames of a split (its distances; its subjects unless `subjects` are given),
    cycling through subjects and distances evenly."""
    split_subjects, distances = _split(split)
    return render_frames(split_subjects if subjects is None else subjects, distances, frames, seed, intrinsics,
                         progress)


def parse_subjects(text: str) -> tuple[str, ...]:
    """Comma-separated subject names; ValueError names the unknown ones (check_subjects)."""
    subjects = tuple(name.strip() for name in text.split(",") if name.strip())
    check_subjects(subjects)
    return subjects


def check_subjects(subjects: tuple[str, ...]) -> None:
    """ValueError naming unknown subjects (or an empty list) and the known ones."""
    unknown = [s for s in subjects if s not in SUBJECTS]
    if unknown or not subjects:
        raise ValueError(f"unknown subject(s) {', '.join(unknown) or '(none given)'} (known: {', '.join(SUBJECTS)})")


def render_frames(
    subjects: tuple[str, ...],
    distances: tuple[float, ...],
    frames: int,
    seed: int = 0,
    intrinsics: Intrinsics | None = None,
    progress: Callable[[int, int], None] | None = None,
    model: SensorModel | None = None,
    yaw_deg: float = YAW_DEG,
) -> Dataset:
    """Render `frames` labelled frames of these SUBJECTS at these nose distances (metres), cycling evenly;
    model: the sensor (default: the renderer's, which training uses), yaw uniform in +-yaw_deg."""
    check_subjects(subjects)
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    intrinsics = intrinsics or Intrinsics()
    meshes = {name: make_subject(SUBJECTS[name]) for name in subjects}
    rng = np.random.default_rng(seed)
    combos = [(s, d) for d in distances for s in subjects]
    h, w = intrinsics.shape
    range_m = np.empty((frames, h, w), np.float32)
    amplitude = np.empty((frames, h, w), np.float32)
    nose_px = np.empty((frames, 2), np.float32)
    nose_xyz = np.empty((frames, 3))
    visible = np.empty(frames, bool)
    yaw = rng.uniform(-yaw_deg, yaw_deg, frames)
    pitch = rng.uniform(-PITCH_DEG, PITCH_DEG, frames)
    jitter = rng.uniform(-CENTRE_JITTER_PX, CENTRE_JITTER_PX, (frames, 2))
    subject, distance = zip(*(combos[i % len(combos)] for i in range(frames)), strict=True)
    for i in range(frames):
        pose = Pose(distance[i], yaw[i], pitch[i], nose_px=(intrinsics.cx + jitter[i, 0], intrinsics.cy + jitter[i, 1]))
        r = render_face(meshes[subject[i]], pose, intrinsics, rng, model)
        range_m[i], amplitude[i] = r.range_m, r.amplitude
        nose_px[i], nose_xyz[i], visible[i] = r.nose_px, r.nose_xyz_m, r.nose_visible
        if progress is not None:
            progress(i + 1, frames)
    return Dataset(range_m, amplitude, nose_px, visible, np.array(distance), yaw, pitch, np.array(subject),
                   intrinsics, nose_xyz)
