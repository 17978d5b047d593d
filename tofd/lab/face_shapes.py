"""Plausible new face shapes: a base mesh deformed by smooth, localized displacement fields (metres).

An identity is a FaceShape: how far its nose tip protrudes, how wide and long its nose is, how high its
bridge, and how full its cheeks, brow and chin are, drawn with a fixed seed (`draw_shape`) over the range adult
faces span. The ranges follow Farkas' anthropometric norms (L. G. Farkas, Anthropometry of the Head and Face,
2nd ed., Raven Press 1994; Farkas et al., International anthropometric study of facial morphology in various
ethnic groups/races, J. Craniofac. Surg. 16(4):615-646, 2005), roughly the adult range of both sexes:
- nasal tip protrusion (sn-prn, subnasale to pronasale along the face's depth): 15-25 mm;
- nose width (al-al, between the alae): 30-40 mm, applied as a ratio to BASE_NOSE_WIDTH_MM (not measured);
- nose height (n-sn, nasion to subnasale): 45-60 mm;
- head size: face breadth (zy-zy) and height (n-gn) span about +-10 % about the adult means of both sexes, here
  one isotropic factor 0.90-1.10 about the nose tip, applied last: the nose measures above are those of a head of
  the base mesh's size and scale with the head.
Bridge height, cheek, brow and chin projections follow no norm here: they vary by a few millimetres (+-3, +-5,
+-3, +-7 mm, our choice) about the base mesh.

Every field is a product of Gaussians and smoothsteps in the head frame relative to the nose tip (x right, y up,
z out of the face; widths of 7-22 mm), faded out behind the face (`FRONT_DEPTH_MM`), so the
surface stays smooth and the mesh's topology and nose-tip vertex are kept. `measure` reads a mesh's
protrusion and nose height at its base mesh's subnasale and nasion vertices; `deform` moves the base mesh to the
drawn targets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.drivers.emulator.render import FaceMesh

PROTRUSION_MM = (15.0, 25.0)  # sn-prn
NOSE_WIDTH_MM = (30.0, 40.0)  # al-al
NOSE_HEIGHT_MM = (45.0, 60.0)  # n-sn
HEAD_SCALE = (0.90, 1.10)  # isotropic, about the nose tip
BRIDGE_MM, CHEEKS_MM, BROW_MM, CHIN_MM = 3.0, 5.0, 3.0, 7.0  # +- about the base mesh
BASE_NOSE_WIDTH_MM = 35.0  # al-al taken for both base meshes (the middle of the norm): the width is a ratio to it
FRONT_DEPTH_MM = 70.0  # fields fade to zero between this and 30 mm more behind the nose tip
LANDMARKS = {"lee_perry_smith": (4909, 5334), "mediapipe_canonical": (2, 168), "ict_face_model": (2189, 1358)}
"""Base mesh -> vertex numbers of its subnasale and nasion: MediaPipe's own landmark numbers; on the head scan and
the ICT model's neutral head the deepest midline vertices 8-22 mm below and 25-60 mm above the nose tip."""


@dataclass(frozen=True, slots=True)
class FaceShape:
    """An identity's targets: protrusion, nose width and nose height (mm, Farkas' measures), the bridge,
    cheek, brow and chin displacements (mm along z, + out of the face) relative to its base mesh, and its head size
    (a factor on the base mesh)."""

    protrusion_mm: float
    nose_width_mm: float
    nose_height_mm: float
    bridge_mm: float = 0.0
    cheeks_mm: float = 0.0
    brow_mm: float = 0.0
    chin_mm: float = 0.0
    head_scale: float = 1.0


@dataclass(frozen=True, slots=True)
class Profile:
    """Measures of a mesh's midline profile, millimetres: sn-prn depth and n-sn height."""

    protrusion_mm: float
    nose_height_mm: float


def draw_shape(seed: int) -> FaceShape:
    """A FaceShape drawn uniformly over the module's ranges with this seed (the same seed, the same face)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.0, 1.0, 4)
    return FaceShape(
        protrusion_mm=float(rng.uniform(*PROTRUSION_MM)),
        nose_width_mm=float(rng.uniform(*NOSE_WIDTH_MM)),
        nose_height_mm=float(rng.uniform(*NOSE_HEIGHT_MM)),
        bridge_mm=float(BRIDGE_MM * u[0]), cheeks_mm=float(CHEEKS_MM * u[1]), brow_mm=float(BROW_MM * u[2]),
        chin_mm=float(CHIN_MM * u[3]), head_scale=float(rng.uniform(*HEAD_SCALE)))


def measure(mesh: FaceMesh, base: str) -> Profile:
    """The mesh's nasal tip protrusion (pronasale z - subnasale z) and nose height (nasion y - subnasale y), mm,
    read at LANDMARKS[base] (a deformed mesh keeps its base mesh's vertex numbering)."""
    sn, n = LANDMARKS[base]
    v = mesh.vertices * 1e3
    return Profile(float(v[mesh.nose, 2] - v[sn, 2]), float(v[n, 1] - v[sn, 1]))


def _gauss(d: np.ndarray, sigma: float) -> np.ndarray:
    return np.exp(-0.5 * (d / sigma) ** 2)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _displacement(base: FaceMesh, shape: FaceShape, protrude_mm: float, lengthen_mm: float) -> np.ndarray:
    """(N, 3) displacement (mm) of the base mesh's vertices: the tip `protrude_mm` forward, the nose `lengthen_mm`
    longer, the width, bridge, cheeks, brow and chin of `shape`; faded out behind the face."""
    rel = (base.vertices - base.vertices[base.nose]) * 1e3
    x, y, z = rel.T
    sn_index, n_index = LANDMARKS[base.name]
    sn, n = rel[sn_index, 1], rel[n_index, 1]
    # nose region: the dorsum above the tip (slow fall-off towards the nasion) and the tip's lower half
    nose_y = np.where(y >= 0, _gauss(y, 0.45 * n), _gauss(y, 0.6 * -sn))
    d = np.zeros_like(rel)
    d[:, 2] += protrude_mm * _gauss(x, 11.0) * nose_y  # the tip and its lobule forward, the face around it still
    # width: the alae spread about the midline at the level just above the subnasale
    d[:, 0] += (shape.nose_width_mm / BASE_NOSE_WIDTH_MM - 1.0) * x * _gauss(x, 20.0) * _gauss(y - 0.4 * sn, 10.0)
    # height: everything between nasion and upper lip moves down, fading in from the nasion, out into the lip
    along = np.where(y >= sn, _smoothstep((n - y) / n), _gauss(y - sn, 8.0))
    d[:, 1] -= lengthen_mm * along * _gauss(x, 22.0)
    d[:, 2] += shape.bridge_mm * _gauss(x, 7.0) * _gauss(y - 0.55 * n, 9.0)
    cheeks = _gauss(np.hypot(x - 45.0, y + 10.0), 18.0) + _gauss(np.hypot(x + 45.0, y + 10.0), 18.0)
    d[:, 2] += shape.cheeks_mm * cheeks
    d[:, 2] += shape.brow_mm * _gauss(x, 35.0) * _gauss(y - n - 8.0, 8.0)
    d[:, 2] += shape.chin_mm * _gauss(np.hypot(x, y + 75.0), 16.0)
    return d * _smoothstep((z + FRONT_DEPTH_MM + 30.0) / 30.0)[:, None]


def deform(base: FaceMesh, shape: FaceShape, name: str) -> FaceMesh:
    """The base mesh (one of LANDMARKS) moved to the shape's protrusion and nose height exactly (as `measure`
    reads them: both are linear in the two fields' amplitudes, solved for), its nose width as a ratio to
    BASE_NOSE_WIDTH_MM, and its bridge, cheek, brow and chin displacements, then scaled by its head size about the
    nose tip (the nose in proportion: its measures are those of a head of the base mesh's size). Same topology,
    same tip vertex."""
    if base.name not in LANDMARKS:
        raise ValueError(f"no landmarks for base mesh {base.name!r} (known: {', '.join(LANDMARKS)})")

    def moved(protrude_mm: float, lengthen_mm: float) -> FaceMesh:
        return base.with_vertices(base.vertices + _displacement(base, shape, protrude_mm, lengthen_mm) / 1e3)

    def profile(protrude_mm: float, lengthen_mm: float) -> np.ndarray:
        p = measure(moved(protrude_mm, lengthen_mm), base.name)
        return np.array([p.protrusion_mm, p.nose_height_mm])

    at0 = profile(0.0, 0.0)
    jacobian = np.stack([profile(1.0, 0.0) - at0, profile(0.0, 1.0) - at0], axis=1)
    protrude, lengthen = np.linalg.solve(jacobian, np.array([shape.protrusion_mm, shape.nose_height_mm]) - at0)
    tip = base.vertices[base.nose]
    return base.with_vertices(tip + (moved(float(protrude), float(lengthen)).vertices - tip) * shape.head_scale,
                              name=name)
