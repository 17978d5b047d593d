"""Describe a recording or ROS bag without replaying it (like `mcap info` / `ros2 bag info`).

Reads FILE to its end and prints its format and version, frames, duration and rate (device clock), camera,
intrinsics (pixels; (0, 0) is the centre of the top-left pixel, as in ROS CameraInfo), the lens model and its
coefficients, the depth unit (metres per raw depth value in the file) and the damage found
(frames the reader could not deliver, and where a truncated or corrupt file ends). --json prints the same as JSON.
A file with no readable frame is a data error (exit 2) saying so and what was lost, never "0 frames".
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from tofd import arguments

LENS_MODELS = {"none": "pinhole (no distortion)", "plumb_bob": "plumb_bob (Brown-Conrady k1, k2, p1, p2, k3)",
               "rational_polynomial": "rational_polynomial (Brown-Conrady with rational k4-k6)",
               "equidistant": "equidistant (fisheye)"}
"""How `tofd info` names each distortion model."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="a tofd recording (.mcap) or a ROS 1 or ROS 2 bag")
    arguments.add_bag_arguments(parser)
    parser.add_argument("--json", action="store_true", help="print the description as JSON")


def damage_found(summary) -> list[str]:  # noqa: ANN001 (tofd.inputs.InputSummary, imported lazily)
    """What an InputSummary says was lost: frames by reason, and where reading stopped early."""
    lost = [f"{n} frame(s) {reason}" for reason, n in sorted(summary.rejected.items())]
    return lost + ([f"reading stopped early, {summary.stopped}"] if summary.stopped else [])


def describe(summary) -> list[str]:  # noqa: ANN001 (tofd.inputs.InputSummary, imported lazily)
    """The lines `tofd info` prints for an InputSummary."""
    s = summary
    fmt = s.format.kind + (f", format {s.format.version}" if s.format.version else "")
    lines = [("file", str(s.path)), ("format", fmt), *s.format.details,
             ("frames", f"{s.frames}" + (f" (frame counters {s.first_counter} to {s.last_counter})"
                                          if s.frames else "")),
             ("duration", f"{s.duration_s:.3f} s (device clock)"),
             ("rate", "-" if math.isnan(s.rate_hz) else f"{s.rate_hz:.2f} frames/s")]
    if s.device is not None:
        lines.append(("camera", f"{s.device.model or 'unknown'} serial {s.device.serial}, firmware "
                                f"{s.device.firmware or '-'}, backend {s.device.backend or '-'}"))
    if s.intrinsics is not None:
        i = s.intrinsics
        lines.append(("intrinsics", f"{i.width}x{i.height} px, fx {i.fx:.3f}, fy {i.fy:.3f}, cx {i.cx:.3f}, "
                                    f"cy {i.cy:.3f} (pixels; (0, 0) = centre of the top-left pixel)"))
        lens = ", ".join(f"{name} {value:.6g}" for name, value in i.coefficients().items())
        lines.append(("lens", LENS_MODELS.get(i.distortion_model, i.distortion_model) + (f": {lens}" if lens else "")))
    if s.depth_unit_m is not None:
        lines.append(("depth unit", f"{s.depth_unit_m:.6g} m per raw value"
                                    + (" (float metres)" if s.depth_unit_m == 1.0 else "")))
    lines.append(("damage", "; ".join(damage_found(s)) or "none found"))
    faults = ", ".join(f"{k} {v}" for k, v in sorted(s.counters.items()) if k not in (*s.rejected, "frames"))
    if faults:
        lines.append(("reader counts", faults))
    width = max(len(name) for name, _ in lines) + 2
    return [f"{name + ':':<{width}}{value}" for name, value in lines]


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.inputs import summarize

    summary = summarize(args.file, arguments.bag_options(args))
    if not summary.frames:
        lost = "; ".join(damage_found(summary)) or "the file holds none"
        raise UsageError(f"{args.file}: nothing readable: no frame ({lost})")
    print(json.dumps(summary.to_dict(), indent=2) if args.json else "\n".join(describe(summary)))
    return 0
