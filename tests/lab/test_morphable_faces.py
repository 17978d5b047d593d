"""Heads of the ICT Face Model: shipped with their licence, drawn reproducibly, person-like and differing
(tests/lab/test_face_shapes.py: no head is a scaled copy of another)."""

from importlib import resources

import numpy as np

from tofd.drivers.emulator.render import Pose, load_face, render_face
from tofd.lab.face_shapes import measure
from tofd.lab.faces import SUBJECTS, make_subject
from tofd.lab.morphable_faces import MESH, draw_identity, identity_modes

HEADS = [s for s in SUBJECTS.values() if s.identity_seed is not None]


def test_the_model_ships_with_its_licence_and_fits_its_mesh():
    data = resources.files("tofd.drivers").joinpath("data")
    assert "MIT License" in data.joinpath("LICENSE.ICT-FaceKit.txt").read_text()
    assert "LICENSE.ICT-FaceKit.txt" in data.joinpath("README.md").read_text()
    neutral, modes = load_face(MESH), identity_modes()
    assert modes.shape[1:] == neutral.vertices.shape and len(modes) >= 30
    assert neutral.faces.min() == 0 and neutral.faces.max() == len(neutral.vertices) - 1
    assert np.argmax(neutral.vertices[:, 2]) == neutral.nose


def test_a_seed_draws_the_same_head_and_another_seed_another():
    a, b = draw_identity(7, "a"), draw_identity(7, "b")
    assert np.array_equal(a.vertices, b.vertices) and a.nose == b.nose
    assert not np.allclose(a.vertices, draw_identity(8, "c").vertices, atol=1e-3)


def test_the_heads_have_adult_noses_that_differ():
    """Nasal tip protrusion and nose height (Farkas' sn-prn and n-sn) of every head in a band around the adult
    range, spread over it: person-like heads, and not one nose."""
    profiles = [measure(make_subject(s), MESH) for s in HEADS]
    protrusion = np.array([p.protrusion_mm for p in profiles])
    height = np.array([p.nose_height_mm for p in profiles])
    assert np.all((8.0 < protrusion) & (protrusion < 32.0)) and np.all((40.0 < height) & (height < 75.0))
    assert protrusion.std() > 2.0 and height.std() > 2.0


def test_a_drawn_head_renders_with_its_nose_tip_in_front():
    head = draw_identity(SUBJECTS["ict_11"].identity_seed, "ict_11")
    r = render_face(head, Pose(0.5, nose_px=(90.0, 70.0)))
    assert r.nose_visible and r.face_mask.sum() > 2000
    assert r.range_m[70, 90] == np.nanmin(r.range_m)  # facing the camera, no other point of the head is nearer
