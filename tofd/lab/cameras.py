"""Camera geometries the lab renders for by name, and the `--intrinsics` option that picks one (a name, six
numbers, or a recording whose intrinsics are read from its header)."""

from __future__ import annotations

import math
from pathlib import Path

from tofd.drivers.intrinsics import Intrinsics


def pinhole(width: int, height: int, f: float) -> Intrinsics:
    """Square pixels of focal length f (pixels), principal point at the image centre."""
    return Intrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


CAMERAS: dict[str, Intrinsics] = {
    "sr3000": Intrinsics(),  # 176x144, 47.5 degrees across
    "320x240": pinhole(320, 240, 160 / math.tan(math.radians(35.0))),  # 70 degrees across
    "k4a-nfov": pinhole(640, 576, 504.0),  # Azure Kinect / Femto NFOV unbinned
    "1024x1024": pinhole(1024, 1024, 500.0),  # Azure Kinect WFOV-like
}
"""Name -> intrinsics (pixels): the SR3000 the model is trained on, and current TOF camera geometries."""

INTRINSICS_HELP = (f"camera geometry: {' | '.join(CAMERAS)}, or WIDTH,HEIGHT,FX,FY,CX,CY (pixels), or a tofd "
                   "recording (its intrinsics); default sr3000")


def parse_intrinsics(text: str) -> Intrinsics:
    """The intrinsics named by `text` (INTRINSICS_HELP); ValueError says what is wrong with it."""
    if text in CAMERAS:
        return CAMERAS[text]
    parts = text.split(",")
    if len(parts) == 6:
        try:
            w, h, fx, fy, cx, cy = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"{text!r}: expected six numbers WIDTH,HEIGHT,FX,FY,CX,CY") from None
        if w != int(w) or h != int(h) or min(w, h) < 8 or not (fx > 0 and fy > 0):
            raise ValueError(f"{text!r}: width and height must be integers >= 8, fx and fy > 0")
        return Intrinsics(int(w), int(h), fx, fy, cx, cy)
    if Path(text).is_file():
        from tofd.drivers.recording.reader import read_recording_info
        from tofd.drivers.source import DriverError

        try:
            info = read_recording_info(text)
        except DriverError as exc:
            raise ValueError(str(exc)) from None
        if info.intrinsics is None:
            raise ValueError(f"{text}: the recording holds no frame (no intrinsics)")
        return info.intrinsics
    raise ValueError(f"{text!r} is not a camera ({', '.join(CAMERAS)}), six numbers or a recording file")
