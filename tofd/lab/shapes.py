"""Analytic test scenes: exact radial range (metres along each pixel's ray) of spheres, planes and a capped disc.

Ideal, noise-free images for the features' tests, the sphere experiment and the benchmark. Amplitude is
Lambertian: gain * cos(incidence) / range^2 (gain = amplitude of a facing surface at 1 m). Pixels whose
ray misses the surface have NaN range and zero amplitude.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tofd.drivers.intrinsics import Intrinsics

DEFAULT_GAIN = 5000.0


@dataclass(frozen=True, slots=True)
class SyntheticImage:
    """Range (metres, NaN = no return) and amplitude images, both (H, W) float64."""

    range_m: np.ndarray
    amplitude: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """Pixels that see the surface."""
        return np.isfinite(self.range_m)

    def over(self, background: SyntheticImage) -> SyntheticImage:
        """This surface in front of `background` (nearest return wins)."""
        front = self.mask & ~(background.range_m < self.range_m)
        return SyntheticImage(np.where(front, self.range_m, background.range_m),
                              np.where(front, self.amplitude, background.amplitude))


def pixel_ray(intrinsics: Intrinsics, pixel: tuple[float, float]) -> np.ndarray:
    """Unit ray (3,) through pixel (u, v)."""
    return intrinsics.pixel_rays(pixel[0], pixel[1])


def _lambertian(rays: np.ndarray, range_m: np.ndarray, normals: np.ndarray, gain: float) -> np.ndarray:
    cosine = np.abs(np.einsum("hwc,hwc->hw", rays, normals))
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(range_m), gain * cosine / range_m**2, 0.0)


def sphere(intrinsics: Intrinsics, apex_range_m: float, radius_m: float,
           apex_px: tuple[float, float] | None = None, gain: float = DEFAULT_GAIN) -> SyntheticImage:
    """A sphere whose nearest point (apex) lies at `apex_range_m` on the ray of pixel `apex_px`.

    apex_px defaults to the pixel nearest the principal point (so the apex is sampled exactly).
    """
    if apex_px is None:
        apex_px = (float(round(intrinsics.cx)), float(round(intrinsics.cy)))
    return sphere_at(intrinsics, pixel_ray(intrinsics, apex_px) * (apex_range_m + radius_m), radius_m, gain)


def sphere_at(intrinsics: Intrinsics, centre_m: np.ndarray, radius_m: float,
              gain: float = DEFAULT_GAIN) -> SyntheticImage:
    """The sphere of `radius_m` about `centre_m` (camera frame, metres): each ray's first hit."""
    centre = np.asarray(centre_m, dtype=np.float64)
    rays = intrinsics.unit_rays()
    along = rays @ centre
    disc = along**2 - (centre @ centre - radius_m**2)
    with np.errstate(invalid="ignore"):
        range_m = np.where(disc >= 0, along - np.sqrt(disc), np.nan)
    normals = (rays * range_m[..., None] - centre) / radius_m
    return SyntheticImage(range_m, _lambertian(rays, range_m, normals, gain))


def plane(intrinsics: Intrinsics, point_m: np.ndarray, normal: np.ndarray,
          gain: float = DEFAULT_GAIN) -> SyntheticImage:
    """The plane through `point_m` (camera frame, metres) with `normal`; only hits in front of the camera."""
    normal = np.asarray(normal, dtype=np.float64)
    normal = normal / np.linalg.norm(normal)
    rays = intrinsics.unit_rays()
    denom = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = float(np.asarray(point_m, dtype=np.float64) @ normal) / denom
    range_m = np.where(np.isfinite(t) & (t > 0), t, np.nan)
    return SyntheticImage(range_m, _lambertian(rays, range_m, np.broadcast_to(normal, rays.shape), gain))


def tilt_normal(tilt_x_deg: float, tilt_y_deg: float) -> np.ndarray:
    """Unit normal facing the camera (z < 0), turned by tilt_x about the y axis and tilt_y about the x axis."""
    ax, ay = np.radians(tilt_x_deg), np.radians(tilt_y_deg)
    return np.array([np.sin(ax) * np.cos(ay), np.sin(ay), -np.cos(ax) * np.cos(ay)])


def tilted_plane(intrinsics: Intrinsics, distance_m: float, tilt_x_deg: float, tilt_y_deg: float,
                 gain: float = DEFAULT_GAIN) -> SyntheticImage:
    """A plane through (0, 0, distance_m) with normal tilt_normal(tilt_x_deg, tilt_y_deg)."""
    return plane(intrinsics, np.array([0.0, 0.0, distance_m]), tilt_normal(tilt_x_deg, tilt_y_deg), gain)


def capped_disc(intrinsics: Intrinsics, distance_m: float, tilt_x_deg: float, tilt_y_deg: float,
                cap_radius_m: float = 0.03, cap_height_m: float = 0.012, disc_radius_m: float = 0.09,
                gain: float = DEFAULT_GAIN) -> SyntheticImage:
    """A flat disc with a spherical cap on its centre (a face with a nose, crudely), facing the camera along
    tilt_normal(tilt_x_deg, tilt_y_deg); the cap's top is at (0, 0, distance_m)."""
    normal = tilt_normal(tilt_x_deg, tilt_y_deg)
    top = np.array([0.0, 0.0, distance_m])
    base = top - cap_height_m * normal
    disc = plane(intrinsics, base, normal, gain)
    from_base = np.linalg.norm(intrinsics.unit_rays() * disc.range_m[..., None] - base, axis=-1)  # in the plane
    with np.errstate(invalid="ignore"):
        outside = ~(from_base <= disc_radius_m)
    disc = SyntheticImage(np.where(outside, np.nan, disc.range_m), np.where(outside, 0.0, disc.amplitude))
    return sphere_at(intrinsics, top - cap_radius_m * normal, cap_radius_m, gain).over(disc)
