"""A disk cache of a face scene's rendered cycle, so that an emulated camera starts in about a second, not ~13 s.

An entry is an uncompressed .npz (no pickle) named by the SHA-256 of everything its images depend on; it lives in
$TOFD_CACHE_DIR, else $XDG_CACHE_HOME/tofd, else ~/.cache/tofd. A missing, damaged or unwritable cache only costs
the render.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import zipfile
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from tofd.drivers.frame import GroundTruth

log = logging.getLogger(__name__)

Pose = tuple[np.ndarray, np.ndarray, GroundTruth]
"""(range_m (H, W) float32, amplitude (H, W) uint16 little-endian, ground truth) of one pose."""


def cache_dir() -> Path:
    """Where entries live (not created here)."""
    if os.environ.get("TOFD_CACHE_DIR"):
        return Path(os.environ["TOFD_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tofd"


def entry_key(parts: Iterable[bytes]) -> str:
    """The entry's name: SHA-256 (hex) of the parts, each length-prefixed so that no two lists collide."""
    digest = hashlib.sha256()
    for part in parts:
        digest.update(len(part).to_bytes(8, "little") + part)
    return digest.hexdigest()


def load(key: str, n_poses: int) -> dict[int, Pose] | None:
    """The poses 0..n_poses-1 of entry `key`, or None when it is missing or unreadable."""
    path = cache_dir() / f"scene-{key}.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            ranges, amplitudes = data["range_m"], data["amplitude"]
            nose_px, visible, nose_xyz = data["nose_px"], data["visible"], data["nose_xyz_m"]
        if not (len(ranges) == len(amplitudes) == len(nose_px) == len(visible) == len(nose_xyz) == n_poses):
            raise ValueError(f"{len(ranges)} poses, expected {n_poses}")
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        log.warning("ignoring the emulator's render cache %s: %s", path, exc)
        return None
    return {i: (ranges[i].astype(np.float32, copy=False), amplitudes[i].astype("<u2", copy=False),
                GroundTruth(nose_px=(float(nose_px[i, 0]), float(nose_px[i, 1])), visible=bool(visible[i]),
                            nose_xyz_m=None if np.isnan(nose_xyz[i]).any() else
                            (float(nose_xyz[i, 0]), float(nose_xyz[i, 1]), float(nose_xyz[i, 2]))))
            for i in range(n_poses)}


def store(key: str, poses: Mapping[int, Pose]) -> None:
    """Write the poses 0..len-1 as entry `key` (temp file + rename, so readers never see half an entry)."""
    order = range(len(poses))
    truths = [poses[i][2] for i in order]
    arrays = {
        "range_m": np.stack([poses[i][0] for i in order]),
        "amplitude": np.stack([poses[i][1] for i in order]),
        "nose_px": np.array([t.nose_px for t in truths], np.float64),
        "visible": np.array([t.visible for t in truths], bool),
        "nose_xyz_m": np.array([t.nose_xyz_m or (np.nan,) * 3 for t in truths], np.float64),
    }
    directory = cache_dir()
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".scene-", suffix=".npz.tmp", dir=directory)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, allow_pickle=False, **arrays)
            os.replace(tmp, directory / f"scene-{key}.npz")
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError as exc:
        log.info("not caching the emulator's rendered scene in %s: %s", directory, exc)
