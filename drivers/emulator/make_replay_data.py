"""Generate the bundled recording: the emulated camera's face moving from 0.35 m to 0.70 m, with ground truth.

    python -m tofd.drivers.emulator.make_replay_data [OUT] [--frames N]

Records frames 0..N-1 of the emulated camera (through the real pyusb path of the USB backend) whose
scene is half a cycle of the emulator's Motion: the nose tip goes from 0.35 m to 0.70 m while the head
turns and nods. The poses are rendered before streaming starts, so the device drops no frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from tofd.drivers.emulator.backend import FaceScene, Motion, open_emulated_camera
from tofd.drivers.recording.writer import RecordingWriter

DEFAULT_OUT = Path(__file__).resolve().parent.parent / "replay_data" / "emulated_face_035_070.mcap"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tofd.drivers.emulator.make_replay_data", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", nargs="?", type=Path, default=DEFAULT_OUT, help=f"default {DEFAULT_OUT}")
    parser.add_argument("--frames", type=int, default=101, help="frames from 0.35 m to 0.70 m (default 101)")
    args = parser.parse_args(argv)
    if args.frames < 2:
        parser.error("--frames: expected >= 2")
    motion = Motion(n_poses=2 * (args.frames - 1))  # frame N-1 is half a cycle: the far end
    scene = FaceScene(motion=motion)
    print(f"rendering {motion.n_poses} poses ...", file=sys.stderr)
    camera = open_emulated_camera(scene=scene, prerender=True)
    config = {"emulator": {"face": scene.mesh.name, "motion": dataclasses.asdict(motion), "seed": scene.seed},
              "camera": {"serial": camera.serial}}
    with camera, RecordingWriter(args.out, config=config) as writer:
        for frame in camera:
            writer.write(frame)
            if frame.frame_counter >= args.frames - 1:
                break
    dropped = camera.counters["device_dropped"]
    print(f"wrote {args.out}: {writer.frames_written} frames, {args.out.stat().st_size / 1e6:.2f} MB, "
          f"{dropped} dropped by the device")
    return 0 if dropped == 0 and writer.frames_written == args.frames else 1


if __name__ == "__main__":
    sys.exit(main())
