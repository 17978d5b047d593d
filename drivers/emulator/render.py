"""SR3000-like rendering of face meshes: radial range and amplitude images with sensor effects.

Shared by the emulated camera and the detector's evaluation data. Everything is vectorised numpy:
triangles are rasterised by expanding each triangle's pixel bounding box, testing the pixel centres
against the triangle, intersecting the pixel's ray with the triangle's plane (exact radial range) and
keeping the nearest hit per pixel.

Sensor model (documented, deliberately simple):
- amplitude = gain * albedo * cos(incidence) / range^2, plus 2 % multiplicative noise;
- range noise: Gaussian; noise_model "amplitude": standard deviation inversely proportional to amplitude
  (range_noise_m at reference_amplitude, capped at max_range_noise_m), "constant": range_noise_m everywhere;
- flying pixels: pixels on a depth discontinuity mix foreground and background range with a random weight
  (flying_pixel_fraction 0: none);
- background: a fronto-parallel wall at wall_distance_m, or none (None: no return, range NaN, amplitude 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from importlib import resources
from typing import Literal

import numpy as np

from tofd.drivers.intrinsics import Intrinsics


@dataclass(frozen=True, slots=True)
class FaceMesh:
    """A triangle mesh in metres, head frame: x right, y up, the face looking along +z."""

    name: str
    vertices: np.ndarray  # (N, 3) float64, metres
    faces: np.ndarray  # (M, 3) int64 vertex indices
    nose: int  # vertex index of the nose tip (pronasale)

    def with_vertices(self, vertices: np.ndarray, name: str | None = None) -> FaceMesh:
        """The same topology with moved vertices (identity variations)."""
        return replace(self, vertices=np.asarray(vertices, dtype=np.float64), name=name or self.name)


FACE_NAMES = ("lee_perry_smith", "mediapipe_canonical", "ict_face_model")  # the last: the ICT model's neutral head


def load_face(name: str) -> FaceMesh:
    """Load a bundled face mesh by name (see drivers/data/README.md for sources and licences)."""
    if name not in FACE_NAMES:
        raise ValueError(f"unknown face {name!r}; bundled faces: {', '.join(FACE_NAMES)}")
    with resources.files("tofd.drivers").joinpath("data", f"{name}.npz").open("rb") as fh:
        data = np.load(fh, allow_pickle=False)
        return FaceMesh(name, data["vertices"].astype(np.float64), data["faces"].astype(np.int64), int(data["nose"]))


@dataclass(frozen=True, slots=True)
class Pose:
    """Where the head is: the nose tip at `distance_m` (radial range) on the ray of pixel `nose_px`."""

    distance_m: float = 0.5
    yaw_deg: float = 0.0  # head turn about the vertical axis; positive turns the face to the image's right
    pitch_deg: float = 0.0  # nod; positive tilts the face up
    roll_deg: float = 0.0  # in-plane tilt
    nose_px: tuple[float, float] | None = None  # (u, v) target pixel of the nose tip; None = principal point


@dataclass(frozen=True, slots=True)
class SensorModel:
    """Parameters of the SR3000-like sensor effects (amplitude in sensor units, ranges in metres)."""

    wall_distance_m: float | None = 1.6  # a fronto-parallel wall behind the head (depth along z); None: no wall
    wall_albedo: float = 0.35
    face_albedo: float = 1.0
    gain: float = 5000.0  # amplitude of an albedo-1 surface facing the camera at 1 m
    range_noise_m: float = 0.002  # range noise standard deviation at reference_amplitude (constant: everywhere)
    noise_model: Literal["amplitude", "constant"] = "amplitude"  # what the range noise depends on
    reference_amplitude: float = 20000.0
    max_range_noise_m: float = 0.15
    amplitude_noise: float = 0.02  # relative standard deviation
    flying_pixel_fraction: float = 0.6  # share of depth-edge pixels that mix foreground and background
    edge_jump_m: float = 0.05  # range step between 4-neighbours that makes a depth edge


@dataclass(slots=True)
class Rendering:
    """One rendered frame and its ground truth."""

    range_m: np.ndarray  # (H, W) float32 radial range, metres
    amplitude: np.ndarray  # (H, W) float32 sensor units
    face_mask: np.ndarray  # (H, W) bool, pixels that see the mesh
    nose_px: tuple[float, float]  # (u, v) projection of the nose tip, pixels
    nose_xyz_m: tuple[float, float, float]  # camera frame, metres
    nose_visible: bool  # inside the image and not occluded


def _rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Head frame (x right, y up, face along +z) -> camera frame (x right, y down, z forward), rotated."""
    y, p, r = np.radians([yaw_deg, pitch_deg, roll_deg])
    face_camera = np.diag([1.0, -1.0, -1.0])  # face looks back at the camera
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    return rz @ rx @ ry @ face_camera


def place_mesh(mesh: FaceMesh, pose: Pose, intrinsics: Intrinsics) -> np.ndarray:
    """(N, 3) camera-frame vertices in metres for a pose."""
    rotated = mesh.vertices @ _rotation(pose.yaw_deg, pose.pitch_deg, pose.roll_deg).T
    u, v = pose.nose_px if pose.nose_px is not None else (intrinsics.cx, intrinsics.cy)
    target = pose.distance_m * intrinsics.pixel_rays(u, v)
    return rotated + (target - rotated[mesh.nose])


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) unit vertex normals facing the camera: area-weighted sums of the faces' normals, each face's
    normal first turned towards the camera (the meshes' winding is not consistent)."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 x area
    normal *= -np.sign(np.einsum("ij,ij->i", normal, tri[:, 0]))[:, None]
    summed = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(summed, faces[:, corner], normal)
    return summed / (np.linalg.norm(summed, axis=1, keepdims=True) + 1e-300)


def rasterize(
    vertices: np.ndarray, faces: np.ndarray, intrinsics: Intrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-hit radial range (NaN where no triangle) and |cos(incidence)| per pixel, both (H, W) float64.

    The range is exact (ray-plane intersection with the hit triangle); the incidence angle uses the vertex
    normals interpolated over the triangle (smooth shading), so amplitude does not show the facets.
    """
    h, w = intrinsics.shape
    faces = faces[np.all(vertices[faces][:, :, 2] > 1e-3, axis=1)]
    uv = intrinsics.project(vertices[faces])  # (M, 3, 2)
    lo = np.maximum(np.ceil(uv.min(axis=1) - 0.5), 0).astype(np.int64)
    hi = np.minimum(np.floor(uv.max(axis=1) + 0.5), [w - 1, h - 1]).astype(np.int64)
    size = np.maximum(hi - lo + 1, 0)
    count = size[:, 0] * size[:, 1]
    keep = count > 0
    faces, uv, lo, size, count = faces[keep], uv[keep], lo[keep], size[keep], count[keep]

    tid = np.repeat(np.arange(len(faces)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    pu = lo[tid, 0] + offset % size[tid, 0]
    pv = lo[tid, 1] + offset // size[tid, 0]

    a, b, c = uv[tid, 0], uv[tid, 1], uv[tid, 2]
    p = np.stack([pu, pv], axis=1).astype(np.float64)

    def edge(p0: np.ndarray, p1: np.ndarray, q: np.ndarray) -> np.ndarray:
        return (p1[:, 0] - p0[:, 0]) * (q[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (q[:, 0] - p0[:, 0])

    bary = np.stack([edge(b, c, p), edge(c, a, p), edge(a, b, p)], axis=1)  # unnormalised barycentrics
    eps = 1e-9
    inside = np.all(bary >= -eps, axis=1) | np.all(bary <= eps, axis=1)
    tid, pu, pv, bary = tid[inside], pu[inside], pv[inside], bary[inside]

    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    rays = intrinsics.unit_rays()[pv, pu]  # (K, 3)
    n = normal[tid]
    with np.errstate(divide="ignore", invalid="ignore"):
        rng_hit = np.einsum("ij,ij->i", n, tri[tid, 0]) / np.einsum("ij,ij->i", n, rays)
    ok = np.isfinite(rng_hit) & (rng_hit > 0)
    pix, rng_hit, tid, bary, rays = (pv * w + pu)[ok], rng_hit[ok], tid[ok], bary[ok], rays[ok]

    order = np.lexsort((rng_hit, pix))
    nearest = order[np.unique(pix[order], return_index=True)[1]]
    vertex_normals = _vertex_normals(vertices, faces)
    weights = bary[nearest] / bary[nearest].sum(axis=1, keepdims=True)
    smooth = np.einsum("ij,ijk->ik", weights, vertex_normals[faces[tid[nearest]]])
    smooth /= np.linalg.norm(smooth, axis=1, keepdims=True) + 1e-300
    range_m = np.full(h * w, np.nan)
    cosine = np.zeros(h * w)
    range_m[pix[nearest]] = rng_hit[nearest]
    cosine[pix[nearest]] = np.abs(np.einsum("ij,ij->i", smooth, rays[nearest]))
    return range_m.reshape(h, w), cosine.reshape(h, w)


def _depth_edges(range_m: np.ndarray, jump_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixels with a 4-neighbour more than jump_m farther away, and that farthest neighbour's range (NaN
    neighbours, no return, are ignored)."""
    padded = np.pad(range_m, 1, mode="edge")
    neighbours = np.stack([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    far = np.fmax.reduce(neighbours, axis=0)
    with np.errstate(invalid="ignore"):
        return far - range_m > jump_m, far


def range_noise_sigma(amplitude: np.ndarray, model: SensorModel) -> np.ndarray:
    """(H, W) range noise standard deviation in metres of the model's noise_model at these amplitudes."""
    if model.noise_model == "constant":
        return np.full(np.shape(amplitude), model.range_noise_m)
    return np.minimum(model.range_noise_m * model.reference_amplitude / np.maximum(amplitude, 1e-6),
                      model.max_range_noise_m)


def sensor_effects(
    range_m: np.ndarray,
    albedo: np.ndarray,
    cosine: np.ndarray,
    rng: np.random.Generator | None,
    model: SensorModel,
) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude from geometry, then noise and flying pixels (skipped when rng is None); float32 (H, W) each.
    Pixels without a return (range NaN) keep range NaN and amplitude 0."""
    with np.errstate(invalid="ignore"):
        amplitude = np.nan_to_num(model.gain * albedo * cosine / range_m**2, nan=0.0)
    if rng is None:
        return range_m.astype(np.float32), amplitude.astype(np.float32)
    edges, far = _depth_edges(range_m, model.edge_jump_m)
    fly = edges & (rng.random(range_m.shape) < model.flying_pixel_fraction)
    weight = rng.random(range_m.shape)
    mixed = np.where(fly, weight * range_m + (1 - weight) * far, range_m)
    amplitude = np.where(fly, amplitude * (0.3 + 0.7 * weight), amplitude)
    sigma = range_noise_sigma(amplitude, model)
    noisy_range = mixed + sigma * rng.standard_normal(range_m.shape)
    noisy_amp = amplitude * (1 + model.amplitude_noise * rng.standard_normal(range_m.shape))
    return noisy_range.astype(np.float32), np.maximum(noisy_amp, 0).astype(np.float32)


def render_face(
    mesh: FaceMesh,
    pose: Pose,
    intrinsics: Intrinsics | None = None,
    rng: np.random.Generator | None = None,
    model: SensorModel | None = None,
) -> Rendering:
    """Render a head in front of a wall; rng=None gives the noise-free image (no flying pixels)."""
    intrinsics = intrinsics or Intrinsics()
    model = model or SensorModel()
    vertices = place_mesh(mesh, pose, intrinsics)
    face_range, face_cos = rasterize(vertices, mesh.faces, intrinsics)
    face_mask = np.isfinite(face_range)

    rays = intrinsics.unit_rays()
    wall_range = rays[..., 2] * np.nan if model.wall_distance_m is None else model.wall_distance_m / rays[..., 2]
    range_m = np.where(face_mask, face_range, wall_range)
    cosine = np.where(face_mask, face_cos, rays[..., 2])
    albedo = np.where(face_mask, model.face_albedo, model.wall_albedo)
    range_out, amplitude = sensor_effects(range_m, albedo, cosine, rng, model)

    nose = vertices[mesh.nose]
    u, v = intrinsics.project(nose)
    row, col = int(round(v)), int(round(u))
    inside = 0 <= row < intrinsics.height and 0 <= col < intrinsics.width
    visible = bool(inside and face_mask[row, col] and abs(face_range[row, col] - np.linalg.norm(nose)) < 0.01)
    nose_xyz_m = (float(nose[0]), float(nose[1]), float(nose[2]))
    return Rendering(range_out, amplitude, face_mask, (float(u), float(v)), nose_xyz_m, visible)
