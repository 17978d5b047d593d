"""Write a recording's or ROS bag's frames out as images, point clouds or arrays (like `rs-convert`).

--to png: per frame <stem>_<counter>_range.png (radial range in millimetres, 16-bit, 0 = invalid) and
<stem>_<counter>_amplitude.png (sensor units, 16-bit, clipped to 65535). --to ply: per frame <stem>_<counter>.ply,
binary little-endian, the valid pixels back-projected through the intrinsics: x, y, z in metres in the camera
frame (x right, y down, z forward) and the amplitude. --to npz: one <stem>.npz (no pickle) with range_m and
amplitude (N, H, W) float32, frame_counter and timestamp_us (N,) int64, and the intrinsics (fx, fy, cx, cy,
width, height). --frames A:B takes the frames at positions A to B-1 in the file (0-based, either end may be left
out, as a Python slice). Damaged frames are left out and counted. Every file is written under a temporary name and
renamed into place when complete (tofd.outputs), so a full disk never leaves a truncated file or spoils an
earlier export at the same path.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

from tofd import arguments

FORMATS = ("png", "ply", "npz")


def frame_range(text: str) -> slice:
    """--frames A:B as a slice of frame positions (A, B >= 0, A < B when both are given)."""
    start, colon, stop = text.partition(":")
    bad = argparse.ArgumentTypeError(f"expected A:B with 0 <= A < B (either may be left out), got {text}")
    if not colon or not all(part.isdigit() for part in (start, stop) if part):
        raise bad
    a, b = (int(start) if start else None), (int(stop) if stop else None)
    if a is not None and b is not None and a >= b:
        raise bad
    return slice(a, b)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="a tofd recording (.mcap) or a ROS 1 or ROS 2 bag")
    arguments.add_bag_arguments(parser)
    parser.add_argument("--to", choices=FORMATS, required=True, help="what to write (see above)")
    parser.add_argument("--frames", type=frame_range, default=slice(None), metavar="A:B",
                        help="frames at positions A..B-1 in the file (default: all)")
    parser.add_argument("--out", type=Path, default=Path("export_out"),
                        help="output directory (default: %(default)s)")


def range_mm(range_m: np.ndarray) -> np.ndarray:
    """(H, W) uint16 millimetres of a range plane in metres; invalid (NaN, <= 0, beyond 65.535 m) -> 0."""
    mm = np.rint(np.nan_to_num(range_m, nan=0.0) * 1000.0)
    return np.where((mm > 0) & (mm <= 65535), mm, 0).astype(np.uint16)


def write_png(path: Path, plane: np.ndarray) -> None:
    """A 16-bit greyscale PNG of a uint16 (H, W) plane (written atomically)."""
    import cv2

    from tofd.outputs import write_bytes

    ok, png = cv2.imencode(".png", plane)
    if not ok:
        raise OSError(f"cannot encode {path} as PNG")
    write_bytes(path, png.tobytes())


def write_ply(path: Path, frame) -> int:  # noqa: ANN001 (tofd.drivers.frame.Frame)
    """The frame's valid pixels as a binary PLY point cloud (x, y, z metres, amplitude), written atomically; the
    number of points."""
    from tofd.outputs import AtomicFile

    points = frame.intrinsics.backproject(frame.range_m).reshape(-1, 3)
    valid = np.isfinite(frame.range_m).reshape(-1) & (frame.range_m.reshape(-1) > 0)
    rows = np.empty(int(valid.sum()), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("amplitude", "<f4")]))
    for axis, name in enumerate("xyz"):
        rows[name] = points[valid, axis]
    rows["amplitude"] = frame.amplitude.reshape(-1)[valid]
    header = (f"ply\nformat binary_little_endian 1.0\ncomment tofd export: metres, camera frame (x right, y down, "
              f"z forward)\nelement vertex {len(rows)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"property float amplitude\nend_header\n")
    with AtomicFile(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(rows.tobytes())
    return len(rows)


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.inputs import InputSummary, describe_input, frames_with_rejects, open_reader
    from tofd.outputs import AtomicFile, prepare_output_dir

    fmt, source = open_reader(args.file, arguments.bag_options(args))
    try:
        out = prepare_output_dir(args.out)
    except BaseException:
        source.close()
        raise
    stem = args.file.name.split(".")[0]
    summary = InputSummary(args.file, describe_input(args.file, fmt, source))
    sel = args.frames
    written = []
    arrays: dict[str, list] = {"range_m": [], "amplitude": [], "frame_counter": [], "timestamp_us": []}
    intrinsics = None
    with source:
        for frame in itertools.islice(frames_with_rejects(source, summary), sel.start, sel.stop):
            summary.add(frame)
            name = f"{stem}_{frame.frame_counter:06d}"
            if args.to == "png":
                amplitude = np.clip(np.rint(np.nan_to_num(frame.amplitude)), 0, 65535).astype(np.uint16)
                write_png(out / f"{name}_range.png", range_mm(frame.range_m))
                write_png(out / f"{name}_amplitude.png", amplitude)
                written += [f"{name}_range.png", f"{name}_amplitude.png"]
            elif args.to == "ply":
                write_ply(out / f"{name}.ply", frame)
                written.append(f"{name}.ply")
            else:
                intrinsics = frame.intrinsics
                for key in arrays:
                    arrays[key].append(getattr(frame, key))
    if args.to == "npz" and intrinsics is not None:
        npz: dict[str, np.ndarray] = {"range_m": np.stack(arrays["range_m"]),
                                      "amplitude": np.stack(arrays["amplitude"]),
                                      "frame_counter": np.asarray(arrays["frame_counter"], np.int64),
                                      "timestamp_us": np.asarray(arrays["timestamp_us"], np.int64),
                                      **{k: np.asarray(v) for k, v in intrinsics.to_dict().items()}}
        with AtomicFile(out / f"{stem}.npz", "wb") as f:
            np.savez_compressed(f.file, allow_pickle=False, **npz)
        written.append(f"{stem}.npz")
    if not summary.frames:
        raise UsageError(f"{args.file}: no frame at positions {sel.start or 0}:{'' if sel.stop is None else sel.stop}")
    left_out = sum(summary.rejected.values())
    print(f"tofd export: {summary.frames} frames (counters {summary.first_counter} to {summary.last_counter}) "
          f"to {out}/ as {args.to}: {len(written)} file(s)"
          + (f"; {left_out} damaged frame(s) left out" if left_out else ""), file=sys.stderr)
    return 0
