"""Camera model of a TOF camera (pinhole plus an optional lens distortion) and back-projection of range maps.

The distortion models and the order of their coefficients are those of ROS sensor_msgs/CameraInfo (OpenCV's):
"plumb_bob" D = (k1, k2, p1, p2, k3), "rational_polynomial" D = (k1, k2, p1, p2, k3, k4, k5, k6) (the
Brown-Conrady model of the Azure Kinect), "equidistant" D = (k1, k2, k3, k4) (OpenCV's fisheye model).
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tofd.drivers.limits import calibration_problem, image_size_problem

SR3000_WIDTH = 176
SR3000_HEIGHT = 144
SR3000_FOV_X_DEG = 47.5

DistortionModel = Literal["none", "plumb_bob", "rational_polynomial", "equidistant"]
COEFFICIENT_NAMES: dict[str, tuple[str, ...]] = {
    "none": (), "plumb_bob": ("k1", "k2", "p1", "p2", "k3"),
    "rational_polynomial": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), "equidistant": ("k1", "k2", "k3", "k4")}
"""The distortion coefficients (CameraInfo's D, in its order) of each distortion model."""
COEFFICIENT_COUNTS: dict[str, int] = {model: len(names) for model, names in COEFFICIENT_NAMES.items()}
"""Number of distortion coefficients of each distortion model."""

UNDISTORT_MAX_ITERATIONS = 30
UNDISTORT_TOLERANCE = 1e-12
"""Newton iterations of undistortion stop when the residual in normalised image coordinates is below this."""


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Camera intrinsics in pixels; pixel (u, v) = (column, row), centre of the top-left pixel is (0, 0).

    distortion_model and distortion (CameraInfo's D, in its order) describe the lens; "none" is an ideal
    pinhole. ValueError names the first field that is out of range: the image size and the calibration must pass
    tofd.drivers.limits (the same rule wherever intrinsics come from).
    """

    width: int = SR3000_WIDTH
    height: int = SR3000_HEIGHT
    fx: float = (SR3000_WIDTH / 2) / math.tan(math.radians(SR3000_FOV_X_DEG / 2))
    fy: float = (SR3000_WIDTH / 2) / math.tan(math.radians(SR3000_FOV_X_DEG / 2))
    cx: float = (SR3000_WIDTH - 1) / 2
    cy: float = (SR3000_HEIGHT - 1) / 2
    distortion_model: DistortionModel = "none"
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, numbers.Integral) or isinstance(value, bool) or value < 1:
                raise ValueError(f"intrinsics.{name}: expected a whole number of pixels >= 1, got {value!r}")
            object.__setattr__(self, name, int(value))
        if (problem := image_size_problem(self.width, self.height)) is not None:
            raise ValueError(f"intrinsics.{'width' if self.width >= self.height else 'height'}: {problem}")
        if (problem := calibration_problem(self.width, self.height, self.fx, self.fy, self.cx, self.cy)) is not None:
            raise ValueError(f"intrinsics.{problem}")
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.distortion_model not in COEFFICIENT_COUNTS:
            raise ValueError(f"intrinsics.distortion_model: expected one of {', '.join(COEFFICIENT_COUNTS)}, "
                             f"got {self.distortion_model!r}")
        try:
            coefficients = tuple(float(c) for c in self.distortion)
        except (TypeError, ValueError):
            raise ValueError(f"intrinsics.distortion: expected a sequence of numbers, got {self.distortion!r}"
                             ) from None
        count = COEFFICIENT_COUNTS[self.distortion_model]
        if len(coefficients) != count or not all(math.isfinite(c) for c in coefficients):
            raise ValueError(f"intrinsics.distortion: model {self.distortion_model!r} takes {count} finite "
                             f"coefficients, got {self.distortion!r}")
        object.__setattr__(self, "distortion", coefficients)

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape (rows, columns)."""
        return self.height, self.width

    @property
    def is_pinhole(self) -> bool:
        """True when the lens has no distortion (model "none")."""
        return self.distortion_model == "none"

    def unit_rays(self) -> np.ndarray:
        """(H, W, 3) float64 unit direction of each pixel's ray in the camera frame (x right, y down, z forward);
        NaN for a pixel no ray of the lens model reaches.

        Computed once per intrinsics and shared (read-only): segmentation and detection ask for it every frame.
        """
        return _unit_rays(self)

    def pixel_rays(self, u: np.ndarray | float, v: np.ndarray | float) -> np.ndarray:
        """(..., 3) float64 unit rays through (sub)pixel coordinates u (column), v (row) of broadcastable shapes
        (the lens distortion undone); NaN where the undistortion does not converge."""
        x = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        y = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        if self.distortion_model == "equidistant":
            return _fisheye_rays(*_broadcast(x, y), self.distortion)
        if not self.is_pinhole:
            x, y = _undistort_radial_tangential(*_broadcast(x, y), self._rational_coefficients())
        rays = np.stack(np.broadcast_arrays(x, y, np.ones_like(x)), axis=-1)
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def backproject(self, range_m: np.ndarray) -> np.ndarray:
        """(H, W, 3) camera-frame points in metres from a radial range map (metres along each pixel's ray)."""
        if range_m.shape != self.shape:
            raise ValueError(f"range_m has shape {range_m.shape}, expected {self.shape}")
        return self.unit_rays() * range_m[..., None]

    def radial_from_z(self, z: np.ndarray) -> np.ndarray:
        """(H, W) radial range along each pixel's ray from a z-depth map (H, W) in the same unit."""
        if z.shape != self.shape:
            raise ValueError(f"z-depth map has shape {z.shape}, expected {self.shape}")
        return z / self.unit_rays()[..., 2]

    def project(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates (u, v) of camera-frame points (..., 3) in metres, through the lens."""
        points = np.asarray(points, dtype=np.float64)
        if self.distortion_model == "equidistant":
            x, y = _fisheye_distort(points, self.distortion)
            return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        z = points[..., 2]
        if not self.is_pinhole:
            x, y = _distort_radial_tangential(points[..., 0] / z, points[..., 1] / z, self._rational_coefficients())
            return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        return np.stack([self.fx * points[..., 0] / z + self.cx, self.fy * points[..., 1] / z + self.cy], axis=-1)

    def project_point(self, xyz: tuple[float, float, float]) -> tuple[float, float]:
        """The pixel (u, v) of one camera-frame point in metres: project() of it, in plain floats for a pinhole
        lens (arrays cost more than the arithmetic for a point a frame)."""
        if not self.is_pinhole:
            u, v = self.project(np.asarray(xyz))
            return float(u), float(v)
        x, y, z = xyz
        return self.fx * x / z + self.cx, self.fy * y / z + self.cy

    def coefficients(self) -> dict[str, float]:
        """The distortion coefficients by name (k1, k2, p1, p2, ...; empty for "none")."""
        return dict(zip(COEFFICIENT_NAMES[self.distortion_model], self.distortion, strict=True))

    def _rational_coefficients(self) -> tuple[float, ...]:
        """(k1, k2, p1, p2, k3, k4, k5, k6) of a plumb_bob or rational_polynomial lens."""
        return self.distortion + (0.0,) * (8 - len(self.distortion))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready fields; a pinhole's dict has only width..cy (as before lens models existed)."""
        d: dict[str, object] = {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
                                "cx": self.cx, "cy": self.cy}
        if not self.is_pinhole:
            d.update(distortion_model=self.distortion_model, distortion=list(self.distortion))
        return d

    @classmethod
    def from_opencv(cls, camera_matrix: object, dist_coeffs: object, width: int, height: int, *,
                    fisheye: bool = False) -> Intrinsics:
        """Intrinsics from an OpenCV calibration: the camera matrix K (3x3, no skew) and the distortion vector D as
        cv2.calibrateCamera gives it, (k1, k2, p1, p2[, k3[, k4, k5, k6]]) (thin-prism and tilt terms must be 0),
        or with ``fisheye=True`` cv2.fisheye's (k1, k2, k3, k4); the image size in pixels. D None or all zero: a
        pinhole. ValueError names the argument that cannot be used."""
        d = _coefficients(dist_coeffs, "dist_coeffs")
        if fisheye:
            model = "equidistant"
        elif np.any(d[8:]):
            raise ValueError(f"dist_coeffs: thin-prism and tilt terms (beyond k6) are not supported, got {d.tolist()}")
        else:
            model = "rational_polynomial" if np.any(d[5:8]) else "plumb_bob"
        return cls._from_lens(width, height, _camera_matrix(camera_matrix, "camera_matrix"), model, d, "dist_coeffs")

    @classmethod
    def from_camera_info(cls, info: object) -> Intrinsics:
        """Intrinsics from a ROS sensor_msgs/CameraInfo: a message (ROS 1 fields K, D; ROS 2 k, d) or a dict of its
        fields (width, height, k, d, distortion_model), or a camera_info YAML loaded as a dict (image_width,
        image_height, camera_matrix, distortion_model, distortion_coefficients). Distortion models: plumb_bob,
        rational_polynomial, equidistant; all-zero D: a pinhole whatever the model. ValueError names the field."""
        def field(*names: str) -> object:
            for name in names:
                value = info.get(name) if isinstance(info, dict) else getattr(info, name, None)
                if value is not None:
                    return value["data"] if isinstance(value, dict) and "data" in value else value
            raise ValueError(f"camera info: no field {' or '.join(names)}")

        try:
            model = str(field("distortion_model")) or "none"
        except ValueError:
            model = "none"
        d = _coefficients(field("d", "D", "distortion_coefficients"), "camera info D")
        if np.any(d) and model not in COEFFICIENT_COUNTS:
            raise ValueError(f"camera info: distortion_model {model!r} is not one of "
                             f"{', '.join(m for m in COEFFICIENT_COUNTS if m != 'none')}")
        return cls._from_lens(_integer(field("width", "image_width"), "camera info width"),
                              _integer(field("height", "image_height"), "camera info height"),
                              _camera_matrix(field("k", "K", "camera_matrix"), "camera info K"), model, d,
                              "camera info D")

    @classmethod
    def _from_lens(cls, width: int, height: int, k: np.ndarray, model: str, d: np.ndarray, where: str) -> Intrinsics:
        """The camera of matrix k (3x3) and lens `model` with coefficients d (zero: a pinhole; zeros past the model's
        count dropped, anything else there refused naming `where`)."""
        fx, fy, cx, cy = float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
        if not np.any(d):
            return cls(width, height, fx, fy, cx, cy)
        n = COEFFICIENT_COUNTS.get(model, 0)
        if np.any(d[n:]):
            raise ValueError(f"{where}: the {model} model takes {n} coefficients, got {d.tolist()}")
        padded = np.zeros(n)
        padded[: min(n, d.size)] = d[:n]
        return cls(width, height, fx, fy, cx, cy, model, tuple(float(v) for v in padded))  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, d: dict) -> Intrinsics:
        """The Intrinsics of a to_dict() dict (a dict without distortion keys is a pinhole)."""
        known = {"width", "height", "fx", "fy", "cx", "cy", "distortion_model", "distortion"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown intrinsics key(s): {', '.join(sorted(unknown))}")
        kwargs = dict(d)
        if "distortion" in kwargs and not isinstance(kwargs["distortion"], str):
            kwargs["distortion"] = tuple(kwargs["distortion"])
        return cls(**kwargs)


def _camera_matrix(value: object, name: str) -> np.ndarray:
    """A 3x3 pinhole matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (3x3 or 9 numbers); ValueError naming `name`."""
    try:
        k = np.asarray(value, dtype=np.float64).reshape(3, 3)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a 3x3 camera matrix, got {value!r}") from None
    if k[0, 1] != 0 or k[1, 0] != 0 or not np.array_equal(k[2], [0.0, 0.0, 1.0]):
        raise ValueError(f"{name}: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {k.tolist()}")
    return k


def _coefficients(value: object, name: str) -> np.ndarray:
    """Distortion coefficients as a flat float64 array (None: none); ValueError naming `name`."""
    try:
        d = np.asarray(() if value is None else value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a sequence of numbers, got {value!r}") from None
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name}: coefficients must be finite, got {d.tolist()}")
    return d


def _integer(value: object, name: str) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise ValueError(f"{name}: expected an integer, got {value!r}")
    return int(value)


@functools.lru_cache(maxsize=8)
def _unit_rays(intrinsics: Intrinsics) -> np.ndarray:
    rays = intrinsics.pixel_rays(np.arange(intrinsics.width)[None, :], np.arange(intrinsics.height)[:, None])
    rays.setflags(write=False)
    return rays


def _broadcast(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    bx, by = np.broadcast_arrays(x, y)
    return bx, by


def _distort_radial_tangential(x: np.ndarray, y: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Distorted normalised coordinates of undistorted ones (x, y) = (X/Z, Y/Z), OpenCV's rational model."""
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x2),
            y * radial + p1 * (r2 + 2 * y2) + 2 * p2 * xy)


def _newton_terms(x: np.ndarray, y: np.ndarray, xd: np.ndarray, yd: np.ndarray, d: tuple[float, ...]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At undistorted (x, y) aiming at distorted (xd, yd): Newton's step (dx, dy) to subtract, the residual's
    length, the radial factor and the Jacobian's determinant (analytic; d(r2)/dx = 2x, d(r2)/dy = 2y)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    radial = num / den
    d_radial = ((k1 + r2 * (2 * k2 + 3 * k3 * r2)) * den - (k4 + r2 * (2 * k5 + 3 * k6 * r2)) * num) / (den * den)
    fx = x * radial + 2 * p1 * xy + p2 * (r2 + 2 * x2) - xd
    fy = y * radial + p1 * (r2 + 2 * y2) + 2 * p2 * xy - yd
    j11 = radial + 2 * x2 * d_radial + 2 * p1 * y + 6 * p2 * x
    j12 = 2 * xy * d_radial + 2 * p1 * x + 2 * p2 * y
    j22 = radial + 2 * y2 * d_radial + 6 * p1 * y + 2 * p2 * x
    det = j11 * j22 - j12 * j12  # j21 == j12
    return (j22 * fx - j12 * fy) / det, (j11 * fy - j12 * fx) / det, np.hypot(fx, fy), radial, det


def _undistort_radial_tangential(xd: np.ndarray, yd: np.ndarray, d: tuple[float, ...]
                                 ) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates whose distortion is (xd, yd): Newton's method on the 2x2 system from
    (xd, yd), each point until its residual is below UNDISTORT_TOLERANCE; NaN where it does not get there."""
    shape = np.shape(xd)
    xd, yd = np.ravel(xd).astype(np.float64), np.ravel(yd).astype(np.float64)
    x, y = xd.copy(), yd.copy()
    active = np.arange(xd.size)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(UNDISTORT_MAX_ITERATIONS):
            if not active.size:
                break
            dx, dy, residual, _, _ = _newton_terms(x[active], y[active], xd[active], yd[active], d)
            x[active] -= dx
            y[active] -= dy
            active = active[~(residual <= UNDISTORT_TOLERANCE)]  # converged before this step: done
        _, _, residual, radial, det = _newton_terms(x, y, xd, yd, d)
        # radial > 0 and det > 0: the solution is on the pixel's side of the axis and the lens maps its
        # neighbourhood one to one (not a root folded back past the radius where the polynomial turns over)
        good = (residual <= UNDISTORT_TOLERANCE * np.maximum(1.0, np.hypot(xd, yd))) & (radial > 0) & (det > 0)
    return np.where(good, x, np.nan).reshape(shape), np.where(good, y, np.nan).reshape(shape)


def _fisheye_theta_d(theta: np.ndarray, d: tuple[float, ...]) -> np.ndarray:
    k1, k2, k3, k4 = d
    t2 = theta * theta
    return theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _fisheye_distort(points: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Distorted normalised coordinates of camera-frame points (..., 3), OpenCV's fisheye (equidistant) model."""
    r = np.hypot(points[..., 0], points[..., 1])
    theta_d = _fisheye_theta_d(np.arctan2(r, points[..., 2]), d)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 0, theta_d / r, 0.0)
    return points[..., 0] * scale, points[..., 1] * scale


def _fisheye_rays(xd: np.ndarray, yd: np.ndarray, d: tuple[float, ...]) -> np.ndarray:
    """(..., 3) unit rays of distorted normalised coordinates, OpenCV's fisheye (equidistant) model: Newton's
    method for the angle theta from the axis with theta_d(theta) = |(xd, yd)|; NaN where it does not converge."""
    k1, k2, k3, k4 = d
    theta_d = np.hypot(xd, yd)
    theta = theta_d.astype(np.float64, copy=True)
    for _ in range(UNDISTORT_MAX_ITERATIONS):
        t2 = theta * theta
        slope = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        with np.errstate(divide="ignore", invalid="ignore"):
            theta = theta - (_fisheye_theta_d(theta, d) - theta_d) / slope
    with np.errstate(invalid="ignore"):
        bad = ~((np.abs(_fisheye_theta_d(theta, d) - theta_d) <= UNDISTORT_TOLERANCE * np.maximum(1.0, theta_d))
                & (theta >= 0) & (theta < np.pi))
        scale = np.where(theta_d > 0, np.sin(theta) / np.where(theta_d > 0, theta_d, 1.0), 1.0)
    rays = np.stack([xd * scale, yd * scale, np.cos(theta)], axis=-1)
    return np.where(bad[..., None], np.nan, rays)
