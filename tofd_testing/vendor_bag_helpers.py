"""Shared by the vendor-recording tests: librealsense's recorder run in a subprocess (either pyrealsense2 version),
and the 3-D foreground `tofd replay` logged, read back from its .rrd."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from tofd.drivers.intrinsics import Intrinsics
from tofd.service.viewer import blueprint as bp
from tofd_testing import HANG_GUARD_S
from tofd_testing.bag_scenes import Scene, depth_units, render, sphere_errors
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config
from tofd_testing.rrd_helpers import read_entities

RECORDER = Path(__file__).with_name("realsense_recorder.py")
LEGACY_VERSION = "2.56.5.9235"
"""The last pyrealsense2 whose recorder writes the ROS 1 .bag."""
RECORD_TIMEOUT_S = 120


def realsense_env(version: str, cache_dir: Path) -> dict[str, str]:
    """The environment running realsense_recorder.py with pyrealsense2 `version` ("current": the test extra's,
    which writes .db3; LEGACY_VERSION: installed once with pip --target into `cache_dir`). Skips, saying why,
    when that pyrealsense2 cannot be installed here."""
    env = {**os.environ}
    if version == "current":
        importlib.metadata.version("pyrealsense2")  # the test extra's; a missing one is an error, not a skip
        return env
    target = cache_dir / f"pyrealsense2-{version}"
    if not (target / "pyrealsense2").is_dir():
        proc = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target",
                               str(target), f"pyrealsense2=={version}"], capture_output=True, text=True,
                              timeout=600)
        if proc.returncode != 0:
            pytest.skip(f"pyrealsense2=={version} cannot be installed here: {proc.stderr.strip()[-300:]}")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(target), env.get("PYTHONPATH", "")]))
    return env


def record_realsense(out: Path, env: dict[str, str], intrinsics: Intrinsics, scene: Scene | Sequence[Scene],
                     units_m: float, n_frames: int = 3, first_number: int = 100) -> Path:
    """`out` written by librealsense's recorder: n_frames of the scene (or one frame of each of a sequence of
    scenes; z16 depth in `units_m`, y8 infrared) at 30 fps device time, frame numbers from first_number, the
    Brown-Conrady lens of `intrinsics`."""
    scenes = [scene] * n_frames if isinstance(scene, Scene) else list(scene)
    images = [render(intrinsics, s)[:2] for s in scenes]
    frames = out.with_suffix(".frames.npz")
    np.savez(frames, depth=np.stack([depth_units(z, units_m) for z, _ in images]),
             infrared=np.stack([np.clip(infrared * 1000, 0, 255).astype(np.uint8) for _, infrared in images]),
             intrinsics=np.array([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy]),
             coeffs=np.array(intrinsics.distortion), depth_units=np.array([units_m]),
             timestamps_ms=1000.0 + np.arange(len(scenes)) * 1000 / 30, first_number=np.array([first_number]))
    proc = subprocess.run([sys.executable, str(RECORDER), str(frames), str(out)], capture_output=True, text=True,
                          env=env, timeout=RECORD_TIMEOUT_S)
    assert proc.returncode == 0 and out.exists(), proc.stderr[-2000:]
    frames.unlink()
    return out


def replay_saving_rrd(path: Path, out: Path) -> subprocess.CompletedProcess:
    """`tofd replay path --out out` with the viewer saving out/<stem>.rrd (the default when Rerun is on); the
    bundled config, with a viewer given all the time it needs to finish the file."""
    env = {k: v for k, v in os.environ.items() if k != "RERUN"} | {"RUST_LOG": "error"}
    config = bundled_config(out.parent / f"{out.name}.toml", pipeline=PATIENT_VIEWER)
    return subprocess.run([sys.executable, "-m", "tofd", "replay", str(path), "--out", str(out), "--config",
                           str(config)], capture_output=True, text=True, timeout=HANG_GUARD_S, env=env)


def logged_foreground(rrd: Path) -> list[np.ndarray]:
    """(N, 3) foreground points of each frame the viewer logged, metres."""
    _, table = read_entities(str(rrd))[bp.FOREGROUND]
    assert table is not None
    column = table.column("Points3D:positions")
    return [np.asarray(column[row].as_py(), np.float64).reshape(-1, 3) for row in range(table.num_rows)]


def assert_on_sphere(points: np.ndarray, scene: Scene, sphere_pixels: int) -> tuple[float, float]:
    """The foreground covers much of the sphere and lies on it: median <= 2 mm, 90th percentile <= 5 mm.
    Returns (median, p90) in metres."""
    errors = sphere_errors(points, scene)
    median, p90 = float(np.median(errors)), float(np.percentile(errors, 90))
    assert len(points) >= 0.3 * sphere_pixels, (len(points), sphere_pixels)  # the segmentation trims the rim
    assert median <= 2e-3 and p90 <= 5e-3, (median, p90)
    return median, p90


def pinhole_errors(intrinsics: Intrinsics, scene: Scene) -> float:
    """Median distance from the sphere of the scene's sphere pixels back-projected without the lens: what the
    test would see if the lens model were ignored."""
    z, _, sphere = render(intrinsics, scene)
    pinhole = Intrinsics(intrinsics.width, intrinsics.height, intrinsics.fx, intrinsics.fy, intrinsics.cx,
                         intrinsics.cy)
    return float(np.median(sphere_errors(pinhole.backproject(pinhole.radial_from_z(z))[sphere], scene)))
