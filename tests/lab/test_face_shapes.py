"""Drawn face shapes: within the anthropometric ranges, smooth, distinct from each other, split without overlap."""

import itertools

import numpy as np
import pytest

from tofd.algorithm.detector import load_model
from tofd.config import default_file
from tofd.drivers.emulator.render import load_face
from tofd.lab.face_shapes import (
    HEAD_SCALE,
    NOSE_HEIGHT_MM,
    PROTRUSION_MM,
    FaceShape,
    deform,
    draw_shape,
    measure,
)
from tofd.lab.faces import (
    CV_SUBJECTS,
    HOLDOUT_SUBJECTS,
    ICT_HOLDOUT_SUBJECTS,
    OLD_HOLDOUT_SUBJECTS,
    SHAPE_TRAIN_SUBJECTS,
    SHAPE_TUNE_SUBJECTS,
    SUBJECTS,
    TEST_SUBJECTS,
    TRAIN_SUBJECTS,
    make_subject,
)

SHAPED = [s for s in SUBJECTS.values() if s.shape_seed is not None]


def _front(vertices: np.ndarray, tip: np.ndarray) -> np.ndarray:
    rel = vertices - tip
    return rel[rel[:, 2] > -0.07]


def test_every_drawn_identity_meets_its_targets_within_the_adult_ranges():
    """Nose measures as drawn, scaled with the head's size (both within their ranges)."""
    assert len(SHAPED) >= 8
    for subject in SHAPED:
        shape = draw_shape(subject.shape_seed)
        got = measure(make_subject(subject), subject.mesh)
        size = shape.head_scale
        assert HEAD_SCALE[0] <= size <= HEAD_SCALE[1]
        assert PROTRUSION_MM[0] <= got.protrusion_mm / size <= PROTRUSION_MM[1]
        assert NOSE_HEIGHT_MM[0] <= got.nose_height_mm / size <= NOSE_HEIGHT_MM[1]
        assert got.protrusion_mm == pytest.approx(shape.protrusion_mm * size, abs=0.05)
        assert got.nose_height_mm == pytest.approx(shape.nose_height_mm * size, abs=0.05)


def test_no_identity_is_a_scaled_copy_of_another():
    """The best anisotropic scale about the nose tip maps no drawn identity's face (a drawn shape, or a head of the
    morphable model) onto another's on the same base mesh (or the base mesh's) within 2 mm: the shapes differ
    locally, not by a scale."""
    drawn = [s for s in SUBJECTS.values() if s.shape_seed is not None or s.identity_seed is not None]
    meshes = {s.name: (s.mesh, make_subject(s)) for s in drawn}
    for base in {m for m, _ in meshes.values()}:
        meshes[base] = (base, load_face(base))
    for (a, (base_a, ma)), (b, (base_b, mb)) in itertools.combinations(meshes.items(), 2):
        if base_a != base_b:
            continue
        keep = (ma.vertices - ma.vertices[ma.nose])[:, 2] > -0.07
        pa, pb = (ma.vertices - ma.vertices[ma.nose])[keep], (mb.vertices - mb.vertices[mb.nose])[keep]
        scale = (pa * pb).sum(axis=0) / (pb * pb).sum(axis=0)
        residual = np.linalg.norm(pa - pb * scale, axis=1)
        assert residual.max() > 0.002, (a, b, residual.max())


@pytest.mark.parametrize("mesh", ["lee_perry_smith", "mediapipe_canonical"])
def test_the_extreme_shapes_fold_no_triangle_of_the_face(mesh):
    """Smooth fields: at the ranges' corners no front triangle turns over and no edge shrinks or stretches by more
    than 2.5x beyond the head's size."""
    base = load_face(mesh)
    tip = base.vertices[base.nose]
    front = np.all((base.vertices[base.faces] - tip)[..., 2] > -0.05, axis=1)
    tri = base.faces[front]

    def normals(v: np.ndarray) -> np.ndarray:
        a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
        return np.cross(b - a, c - a)

    def edges(v: np.ndarray) -> np.ndarray:
        return np.linalg.norm(v[tri] - v[np.roll(tri, 1, axis=1)], axis=-1)

    for p, w, h, sign, size in itertools.product((15.0, 25.0), (30.0, 40.0), (45.0, 60.0), (-1.0, 1.0),
                                                 HEAD_SCALE):
        shape = FaceShape(p, w, h, 3.0 * sign, 5.0 * sign, 3.0 * sign, 7.0 * sign, size)
        moved = deform(base, shape, "corner").vertices
        assert np.all((normals(moved) * normals(base.vertices)).sum(axis=1) > 0)
        ratio = edges(moved) / edges(base.vertices) / size  # the head's size apart
        assert 0.4 < ratio.min() and ratio.max() < 2.5
        assert np.argmax(moved[:, 2]) == base.nose  # the tip stays the front-most point


def test_the_identity_lists_do_not_overlap():
    held = set(HOLDOUT_SUBJECTS)
    assert held.isdisjoint({*SHAPE_TRAIN_SUBJECTS, *SHAPE_TUNE_SUBJECTS, *TRAIN_SUBJECTS, *CV_SUBJECTS,
                            *TEST_SUBJECTS, *OLD_HOLDOUT_SUBJECTS})
    assert set(SHAPE_TRAIN_SUBJECTS).isdisjoint(SHAPE_TUNE_SUBJECTS)
    drawn = (*SHAPE_TRAIN_SUBJECTS, *SHAPE_TUNE_SUBJECTS, *held)
    assert all((SUBJECTS[s].shape_seed is None) != (SUBJECTS[s].identity_seed is None) for s in drawn)
    assert len({SUBJECTS[s].mesh for s in held}) == 3  # held-out shapes on both base meshes, and the model's heads
    assert set(ICT_HOLDOUT_SUBJECTS) < held
    seeds = [SUBJECTS[s].identity_seed for s in SUBJECTS if SUBJECTS[s].identity_seed is not None]
    assert len(seeds) == len(set(seeds)) >= 16  # every head its own draw


def test_the_shipped_model_is_trained_on_the_training_shapes_and_no_test_identity():
    """config/nose_model.json as tofd/commands/train.py documents it: the drawn training shapes are in, and no tuning,
    held-out or test identity ever is (the benches' unseen-face numbers depend on it)."""
    subjects = set(load_model(default_file("nose_model.json")).training["subjects"])
    assert set(SHAPE_TRAIN_SUBJECTS) <= subjects and set(CV_SUBJECTS) <= subjects
    assert subjects.isdisjoint({*SHAPE_TUNE_SUBJECTS, *HOLDOUT_SUBJECTS, *OLD_HOLDOUT_SUBJECTS, *TEST_SUBJECTS})
