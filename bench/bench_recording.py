"""Recording and replay cost on the bundled emulated-camera clip: write ms/frame, bytes/frame, replay fps (CPU
time of this process, so that other load on the machine does not count).

    python bench/bench_recording.py [--repeats 5] [--json bench/results/recording.json]

Baseline measured in the same run: the same frames written as uncompressed .npy planes (np.save, one
file per plane) and read back. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from report import write_json

from tofd.drivers.recording.replay import ReplaySource, iter_frames
from tofd.drivers.recording.writer import RecordingWriter

CLIP = Path(__file__).resolve().parent.parent / "replay_data" / "emulated_face_035_070.mcap"


def bench(repeats: int) -> dict:
    frames = list(iter_frames(CLIP))
    n = len(frames)
    rows: dict[str, list[float]] = {"write_ms": [], "replay_fps": [], "npy_write_ms": [], "npy_read_fps": []}
    size = npy_size = 0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        npy_dir = Path(tmp) / "npy"
        npy_dir.mkdir()
        for _ in range(repeats):
            t = time.process_time()
            with RecordingWriter(path, fsync_interval_s=None) as writer:
                for frame in frames:
                    writer.write(frame)
            rows["write_ms"].append((time.process_time() - t) / n * 1e3)
            size = path.stat().st_size
            t = time.process_time()
            count = sum(1 for _ in ReplaySource(path))
            rows["replay_fps"].append(count / (time.process_time() - t))

            t = time.process_time()
            for i, frame in enumerate(frames):
                np.save(npy_dir / f"r{i}.npy", frame.range_m)
                np.save(npy_dir / f"a{i}.npy", frame.amplitude)
            rows["npy_write_ms"].append((time.process_time() - t) / n * 1e3)
            npy_size = sum(p.stat().st_size for p in npy_dir.iterdir())
            t = time.process_time()
            for i in range(n):
                np.load(npy_dir / f"r{i}.npy", allow_pickle=False)
                np.load(npy_dir / f"a{i}.npy", allow_pickle=False)
            rows["npy_read_fps"].append(n / (time.process_time() - t))
    med = {k: statistics.median(v) for k, v in rows.items()}
    return {
        "title": "Recording and replay cost", "about": __doc__.split("\n\n")[0].replace("\n", " "),
        "machine": platform.platform(), "cpu_count": os.cpu_count(),
        "frames": n, "repeats": repeats,
        "mcap_bytes_per_frame": size / n, "npy_bytes_per_frame": npy_size / n,
        "compression_vs_npy": npy_size / size,
        **{f"median_{k}": v for k, v in med.items()},
        "write_cost_vs_npy": med["write_ms"] / med["npy_write_ms"],
        "replay_vs_npy_read": med["replay_fps"] / med["npy_read_fps"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", type=Path, default=Path("bench/results/recording.json"))
    args = parser.parse_args()
    result = bench(args.repeats)
    print(f"{'':28}{'tofd MCAP':>12}{'npy baseline':>14}{'ratio':>8}")
    print(f"{'bytes / frame':28}{result['mcap_bytes_per_frame']:12.0f}{result['npy_bytes_per_frame']:14.0f}"
          f"{1 / result['compression_vs_npy']:8.2f}")
    print(f"{'write ms / frame (median)':28}{result['median_write_ms']:12.2f}{result['median_npy_write_ms']:14.2f}"
          f"{result['write_cost_vs_npy']:8.2f}")
    print(f"{'lossless replay fps (median)':28}{result['median_replay_fps']:12.0f}"
          f"{result['median_npy_read_fps']:14.0f}{result['replay_vs_npy_read']:8.2f}")
    write_json(args.json, result)


if __name__ == "__main__":
    main()
