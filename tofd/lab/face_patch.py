"""The NFFT features of one face surface read at the same surface points from several cameras.

A noise-free rendered head (tofd.drivers.emulator.render, its nose tip at `distance_m`) is segmented to the face within
`MASK_RADIUS_M` of the true tip; its NFFT fields c0, c2, s2 (tofd.algorithm.features.nfft) are read at the
projections of the true tip and of points beside it (`PROBES_M`), and eps0 = c0^2, eps2 = c2^2 + s2^2 there.

Reading: the fields are band-limited (tofd.algorithm.band) and every camera the sampling check admits
(tofd.algorithm.features.sampling) samples them several times finer than their band edge, so a cubic spline between
pixels reproduces them at any point. Reading them linearly between pixels cuts a peak such as the tip's by a share
that grows with the pixel pitch, which would make a coarse camera read low where its features are right.

Sampling phase: each camera is rendered with its principal point shifted by fractions of a pixel (`PHASES_PX`). The
renderer samples the mesh at pixel centres, so where the pixels are coarse the mesh's detail beyond their Nyquist
frequency aliases into the band and the value at a point moves with the phase (no setting of the features can undo
that; a real pixel, which averages its footprint, suppresses it). The mean over phases is what a camera measures of
the surface, the spread over phases what its sampling adds to one frame.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from tofd.algorithm.features import NFFTFeatures
from tofd.algorithm.features.operators import eccentricity_transfer
from tofd.algorithm.params import FeatureConfig
from tofd.drivers.emulator.render import FaceMesh, Pose, load_face, render_face
from tofd.drivers.intrinsics import Intrinsics

MASK_RADIUS_M = 0.09  # metres: the face patch, points this near the true nose tip
PROBES_M = ((0.0, 0.0, 0.0), (0.015, 0.0, 0.0), (0.0, 0.02, 0.0))  # metres: the tip, and 1.5 cm right, 2 cm below
POSE = (10.0, 5.0)  # yaw, pitch, degrees: the face turned a little, so the tip is not a symmetric apex
PHASES_PX = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5), (0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75))
"""Principal-point shifts (u, v), pixels: the sampling phases a camera is rendered at."""


@dataclass(frozen=True, slots=True)
class PatchReading:
    """eps0, eps2 (m^2) at each probe (P,) of one camera at one distance: mean over the sampling phases, and the
    largest deviation of one phase's tip eps0 from that mean (relative)."""

    camera: str
    distance_m: float
    eps0: tuple[float, ...]
    eps2: tuple[float, ...]
    phase_spread: float
    linear_tip_eps0: float  # the tip's eps0 read linearly between pixels (phase 0), for comparison


def probe_features(mesh: FaceMesh, intrinsics: Intrinsics, distance_m: float, cfg: FeatureConfig,
                   order: int = 3) -> np.ndarray:
    """(P, 2) eps0, eps2 (m^2) at the probes of a noise-free rendering, the fields read with a spline of `order`
    (3: cubic, 1: linear between pixels)."""
    r = render_face(mesh, Pose(distance_m, *POSE), intrinsics, rng=None)
    range_m = r.range_m.astype(np.float64)
    tip = np.asarray(r.nose_xyz_m)
    mask = r.face_mask & (np.linalg.norm(intrinsics.backproject(range_m) - tip, axis=-1) < MASK_RADIUS_M)
    fields = NFFTFeatures(intrinsics, cfg, eccentricity_transfer(cfg)).filtered(range_m, mask)
    uv = intrinsics.project(tip + np.asarray(PROBES_M))  # (P, 2)
    c0, c2, s2 = (map_coordinates(np.nan_to_num(f), [uv[:, 1], uv[:, 0]], order=order) for f in fields)
    return np.stack([c0 * c0, c2 * c2 + s2 * s2], axis=1)


def read_patch(camera: str, intrinsics: Intrinsics, distance_m: float, cfg: FeatureConfig,
               phases_px: tuple[tuple[float, float], ...] = PHASES_PX, mesh: FaceMesh | None = None) -> PatchReading:
    """The face patch's features at the probes seen by one camera at one distance, over the sampling phases."""
    mesh = mesh or load_face("lee_perry_smith")
    values = np.stack([probe_features(mesh, dataclasses.replace(intrinsics, cx=intrinsics.cx + du,
                                                                cy=intrinsics.cy + dv), distance_m, cfg)
                       for du, dv in phases_px])  # (phases, P, 2)
    mean = values.mean(axis=0)
    spread = float(np.max(np.abs(values[:, 0, 0] / mean[0, 0] - 1.0)))
    linear = float(probe_features(mesh, intrinsics, distance_m, cfg, order=1)[0, 0])
    return PatchReading(camera, float(distance_m), tuple(map(float, mean[:, 0])), tuple(map(float, mean[:, 1])),
                        spread, linear)
