"""Emulated SR3000 streaming through the real pyusb path: sustained fps, host cost per frame, device drops.

    /work/venv/bin/python bench/bench_usb.py [--seconds 3] [--json bench/results/usb.json]

Cases: the protocol's default 30 fps (INT_TIME code 30) with the face scene and with the test pattern,
and the fastest the emulator goes (INT_TIME code 0, no readout: a frame every 0.8 ms = 1250 fps offered),
which measures what the host side (pyusb transfer + CRC + parse + metres conversion) sustains.
Baseline in the same run: the bare cost of the conversion alone (check_frame + raw_to_range_m) per frame.
"""

from __future__ import annotations

import argparse
import time
import zlib
from pathlib import Path

import numpy as np
from report import write_json

from tofd.drivers import sr3000
from tofd.drivers.emulator.backend import EmulatedCamera, EmulatedSR3000, FaceScene, Motion
from tofd.drivers.usb import protocol as p

CASES = [  # name, INT_TIME code, readout_s, test pattern
    ("30fps_scene", 30, 0.0085, False),
    ("30fps_pattern", 30, 0.0085, True),
    ("max_pattern", 0, 0.0, True),
    ("max_scene", 0, 0.0, False),
]


def run_case(int_time_code: int, readout_s: float, pattern: bool, seconds: float, scene: FaceScene) -> dict:
    camera = EmulatedCamera(EmulatedSR3000(scene=scene, readout_s=readout_s), int_time_code=int_time_code,
                            read_timeout_s=0.2)
    if pattern:
        camera.set_register(p.Register.DATA_SOURCE, 1)
    gaps_ms = []
    with camera:
        start = time.perf_counter()
        last = start
        n = 0
        for _ in camera:
            now = time.perf_counter()
            gaps_ms.append((now - last) * 1e3)
            last = now
            n += 1
            if now - start >= seconds:
                break
        elapsed = time.perf_counter() - start
    offered_fps = 1 / (4 * sr3000.integration_time_us(int_time_code) * 1e-6 + readout_s)
    return {"offered_fps": offered_fps, "delivered_fps": n / elapsed, "frames": n,
            "device_dropped": camera.counters["device_dropped"],
            "p50_interval_ms": float(np.percentile(gaps_ms[1:], 50)),
            "p99_interval_ms": float(np.percentile(gaps_ms[1:], 99))}


def conversion_baseline_ms(repeats: int = 300) -> float:
    """Host work per frame without USB: validate CRCs and convert a test-pattern frame to metres."""
    d, a = p.pattern_planes()
    payload = d.tobytes() + a.tobytes()
    frame = p.FrameHeader(0, 0, 20000, 30, 5, 1, 0, 6200, zlib.crc32(payload)).pack() + payload
    start = time.perf_counter()
    for _ in range(repeats):
        header = p.check_frame(frame)
        dist, amp = p.split_payload(memoryview(frame)[p.HEADER_LEN:])
        sr3000.raw_to_range_m(dist, header.mod_freq_khz)
        amp.astype(np.float32)
    return (time.perf_counter() - start) / repeats * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--json", type=Path, default=Path(__file__).parent / "results" / "usb.json")
    args = parser.parse_args()
    scene = FaceScene(motion=Motion(n_poses=240))
    scene.prerender()  # rendering is the scene's one-off cost, not streaming's
    results = {"conversion_baseline_ms": conversion_baseline_ms()}
    print(f"baseline: CRC check + metres conversion {results['conversion_baseline_ms']:.3f} ms/frame")
    print(f"{'case':16} {'offered':>8} {'delivered':>9} {'frames':>7} {'dropped':>7} {'p50 ms':>7} {'p99 ms':>7}")
    for name, code, readout, pattern in CASES:
        r = run_case(code, readout, pattern, args.seconds, scene)
        results[name] = r
        print(f"{name:16} {r['offered_fps']:8.1f} {r['delivered_fps']:9.1f} {r['frames']:7d} "
              f"{r['device_dropped']:7d} {r['p50_interval_ms']:7.2f} {r['p99_interval_ms']:7.2f}")
    write_json(args.json, results)


if __name__ == "__main__":
    main()
