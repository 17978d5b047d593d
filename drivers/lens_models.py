"""Vendors' lens models as tofd Intrinsics: the one mapping of librealsense's and the Orbbec SDK's distortion
models onto ROS CameraInfo's, used by their recordings (tofd.drivers.bags) and their live cameras alike.

tofd computes ROS CameraInfo's three distortion models (REP 104 / image_geometry), with D in ROS order:
plumb_bob (k1, k2, p1, p2, k3), rational_polynomial (k1, k2, p1, p2, k3, k4, k5, k6) and equidistant (k1..k4,
the Kannala-Brandt fisheye). Vendor names map onto them here (librealsense "Brown Conrady" = plumb_bob, "Kannala
Brandt4" = equidistant; the Orbbec SDK's OBCameraDistortionModel numbers, whose coefficients come as
k1..k6, p1, p2). All-zero coefficients are a pinhole camera whatever the model is called; a model tofd cannot
compute with non-zero coefficients is refused rather than approximated.
"""

from __future__ import annotations

import dataclasses
from typing import Any, cast

import numpy as np

from tofd.drivers.intrinsics import COEFFICIENT_COUNTS, DistortionModel, Intrinsics
from tofd.drivers.source import DriverError

ROS_LENS_MODELS = {name: n for name, n in COEFFICIENT_COUNTS.items() if n}
"""ROS distortion_model -> number of coefficients (tofd.drivers.intrinsics' models but the pinhole)."""
VENDOR_LENS_MODELS: dict[str, str | None] = {
    "Brown Conrady": "plumb_bob",  # librealsense RS2_DISTORTION_BROWN_CONRADY
    "Kannala Brandt4": "equidistant",  # RS2_DISTORTION_KANNALA_BRANDT4 (T265)
    "None": None,
    "Modified Brown Conrady": None,  # D400 colour; computed only with zero coefficients
    "Inverse Brown Conrady": None,  # D400 depth (zero coefficients)
    "Ftheta": None,
}
"""librealsense's model names (its rs2_distortion_to_string) -> ROS name, None where tofd has no equivalent."""
ORBBEC_LENS_MODELS: dict[int, tuple[str | None, tuple[int, ...]]] = {
    0: (None, ()),  # OB_DISTORTION_NONE
    1: (None, ()),  # OB_DISTORTION_MODIFIED_BROWN_CONRADY
    2: (None, ()),  # OB_DISTORTION_INVERSE_BROWN_CONRADY
    3: ("plumb_bob", (0, 1, 6, 7, 2)),  # OB_DISTORTION_BROWN_CONRADY
    4: ("rational_polynomial", (0, 1, 6, 7, 2, 3, 4, 5)),  # OB_DISTORTION_BROWN_CONRADY_K6
    5: ("equidistant", (0, 1, 2, 3)),  # OB_DISTORTION_KANNALA_BRANDT4
}
"""OBCameraDistortionModel -> (ROS name, indices into the SDK's [k1..k6, p1, p2] giving ROS order)."""


class LensError(DriverError):
    """A calibration tofd cannot compute with: no focal lengths or size, a model it has no equivalent of."""


def lens_intrinsics(width: int, height: int, k: tuple[float, float, float, float], model: str | None,
                    coefficients: Any, where: str) -> Intrinsics:
    """Intrinsics of a camera: size in pixels, (fx, fy, cx, cy) in pixels, a ROS or librealsense distortion model
    name and its coefficients; LensError (naming `where`) when unusable."""
    fx, fy, cx, cy = (float(v) for v in k)
    try:
        base = Intrinsics(int(width), int(height), fx, fy, cx, cy)
    except ValueError as exc:
        raise LensError(f"{where}: no usable calibration (fx, fy, cx, cy = {[fx, fy, cx, cy]}, {width}x{height}): "
                        f"{exc}") from None
    d = np.asarray(coefficients if coefficients is not None else (), dtype=np.float64).ravel()
    if not np.isfinite(d).all():
        raise LensError(f"{where}: distortion coefficients {d.tolist()} are not finite")
    if not np.any(d):
        return base
    name = model or ""
    ros_name = VENDOR_LENS_MODELS.get(name, name) if name not in ROS_LENS_MODELS else name
    if ros_name not in ROS_LENS_MODELS:
        known = ", ".join(list(ROS_LENS_MODELS) + [m for m, r in VENDOR_LENS_MODELS.items() if r])
        raise LensError(f"{where}: distortion model {name!r} with coefficients {d.tolist()} is not supported "
                        f"(supported: {known})")
    n = ROS_LENS_MODELS[ros_name]
    if np.any(d[n:]):
        raise LensError(f"{where}: {ros_name} takes {n} coefficients, got {d.tolist()}")
    padded = np.zeros(n)
    padded[:min(n, d.size)] = d[:n]
    return dataclasses.replace(base, distortion_model=cast(DistortionModel, ros_name),
                               distortion=tuple(float(v) for v in padded))


def orbbec_lens_intrinsics(width: int, height: int, k: tuple[float, ...], model: int,
                           coefficients: tuple[float, ...], where: str) -> Intrinsics:
    """Intrinsics of an Orbbec SDK stream profile: [fx, fy, cx, cy], OBCameraDistortionModel and the SDK's
    [k1, k2, k3, k4, k5, k6, p1, p2]."""
    if model not in ORBBEC_LENS_MODELS:
        raise LensError(f"{where}: Orbbec distortion model {model} is unknown (known: "
                        f"{', '.join(map(str, ORBBEC_LENS_MODELS))})")
    ros_name, order = ORBBEC_LENS_MODELS[model]
    if ros_name is None:
        return lens_intrinsics(width, height, (k[0], k[1], k[2], k[3]), f"Orbbec model {model}", coefficients, where)
    picked = [coefficients[i] for i in order]
    unused = [c for i, c in enumerate(coefficients) if i not in order]
    if any(unused):
        raise LensError(f"{where}: Orbbec model {model} ({ros_name}) with coefficients {list(coefficients)} "
                        "has non-zero terms the model does not use")
    return lens_intrinsics(width, height, (k[0], k[1], k[2], k[3]), ros_name, picked, where)
