"""Heads drawn from the ICT Face Model Light, a linear morphable model of light-stage scans of real people.

An identity is the model's neutral head plus its identity shape modes (PCA of registered scans, metres; the first
40 of 100 are bundled: drivers/data/README.md) weighted by independent standard normal draws from one seed, as
ICT-FaceKit samples random identities. A seed is a person-like head of its own, not a deformation of another mesh:
it changes the whole face -- nose, cheeks, brow, jaw and head size -- the way the scanned people differ.
"""

from __future__ import annotations

from functools import cache
from importlib import resources

import numpy as np

from tofd.drivers.emulator.render import FaceMesh, load_face

MESH = "ict_face_model"  # tofd.drivers.emulator.render.FACE_NAMES
TIP_SEARCH_M = 0.015  # the drawn head's nose tip: its front-most vertex within this (x, y) of the neutral's tip


@cache
def identity_modes() -> np.ndarray:
    """The bundled identity shape modes, (K, N, 3) metres, for the vertices of load_face(MESH)."""
    with resources.files("tofd.drivers").joinpath("data", f"{MESH}.npz").open("rb") as fh:
        data = np.load(fh, allow_pickle=False)
        return data["modes"].astype(np.float64) * float(data["mode_step_m"])


def draw_identity(seed: int, name: str) -> FaceMesh:
    """The head of weights w ~ N(0, 1)^K drawn with `seed`: neutral + sum_k w_k mode_k, its nose tip re-found."""
    neutral, modes = load_face(MESH), identity_modes()
    weights = np.random.default_rng(seed).standard_normal(len(modes))
    vertices = neutral.vertices + np.tensordot(weights, modes, axes=1)
    tip = vertices[neutral.nose]
    near = np.flatnonzero(np.hypot(vertices[:, 0] - tip[0], vertices[:, 1] - tip[1]) < TIP_SEARCH_M)
    nose = int(near[np.argmax(vertices[near, 2])])
    return FaceMesh(name, vertices, neutral.faces, nose)
