"""Intrinsics, lens model included, from what ROS bags and vendors' recordings say about a camera: a
sensor_msgs/CameraInfo (K, D and distortion_model) or a vendor's model name and coefficients (the mapping of
tofd.drivers.lens_models, its LensError as BagError).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from tofd.drivers import lens_models
from tofd.drivers.bags.scan import BagError
from tofd.drivers.intrinsics import Intrinsics


def _bag_lens(mapping: Callable[..., Intrinsics], *args: Any) -> Intrinsics:
    try:
        return mapping(*args)
    except lens_models.LensError as exc:
        raise BagError(str(exc)) from None


def lens_intrinsics(width: int, height: int, k: tuple[float, float, float, float], model: str | None,
                    coefficients: Any, where: str) -> Intrinsics:
    """tofd.drivers.lens_models.lens_intrinsics; BagError (naming `where`) when unusable."""
    return _bag_lens(lens_models.lens_intrinsics, width, height, k, model, coefficients, where)


def orbbec_lens_intrinsics(width: int, height: int, k: tuple[float, ...], model: int,
                           coefficients: tuple[float, ...], where: str) -> Intrinsics:
    """tofd.drivers.lens_models.orbbec_lens_intrinsics; BagError (naming `where`) when unusable."""
    return _bag_lens(lens_models.orbbec_lens_intrinsics, width, height, k, model, coefficients, where)


def camera_info_intrinsics(msg: Any, topic: str) -> Intrinsics:
    """Intrinsics of a sensor_msgs/CameraInfo (ROS 1 names K, D; ROS 2 k, d): K's focal lengths and principal
    point (ROS and tofd both put pixel centres at integer coordinates), its size, distortion model and D."""
    k = np.asarray(_field(msg, "k"), dtype=np.float64)
    return lens_intrinsics(int(msg.width), int(msg.height), (k[0], k[4], k[2], k[5]), str(msg.distortion_model),
                           _field(msg, "d"), topic)


def _field(msg: object, name: str) -> Any:
    """A CameraInfo matrix by its ROS 2 name (k, d) or ROS 1 name (K, D)."""
    return getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper())

