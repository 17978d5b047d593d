"""Run the live service: attach to the camera, process frames, stream to Rerun, serve /healthz and /metrics.

--foxglove HOST:PORT also serves the live stream to Foxglove (its WebSocket protocol; 127.0.0.1 by default).
Attaches to the camera of the config's [camera] kind (or --camera: sr3000, realsense, orbbec, k4a) with its
serial (or --serial, else the first one found), to the emulated SR3000 with --emulate, or with --playback FILE
to a recording the camera's own SDK plays as its device, in real time, through the same code as the camera.
Live queues are latest-wins: when processing falls behind, the oldest frames are dropped and counted in the drop
ledger. SIGTERM/SIGINT drain the queues and exit 0 (also while
the camera or the emulated scene is still being prepared).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from dataclasses import replace
from pathlib import Path

from tofd import arguments
from tofd.service.daemon import RERUN_SPEC_HELP
from tofd.service.foxglove.spec import FOXGLOVE_SPEC_HELP, parse_foxglove_spec

log = logging.getLogger(__name__)

EXIT_AT_ONCE = True  # tofd.cli.main: no interpreter teardown after the service returns (the SIGTERM bound)


class Stopped(BaseException):
    """SIGTERM or SIGINT arrived before the pipeline took over the signals (a BaseException, like
    KeyboardInterrupt, so that no `except Exception` on the way swallows it)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=None, help="config file (default: the bundled tofd.toml)")
    parser.add_argument("--emulate", action="store_true", help="use the emulated SR3000 camera (no hardware)")
    arguments.add_camera_arguments(parser)
    parser.add_argument("--rerun", default=None, metavar="SINK",
                        help=f"{RERUN_SPEC_HELP}; save:PATH writes numbered segments beside PATH "
                             "(STEM.00000.rrd, ...; [rerun] rotate_mb, keep_files)")
    parser.add_argument("--foxglove", default=None, metavar="HOST:PORT", help=FOXGLOVE_SPEC_HELP)
    parser.add_argument("--frames", type=arguments.positive_int, default=None, metavar="N", help="stop after N frames")
    parser.add_argument("--health-port", type=int, default=None, metavar="PORT",
                        help="port of /healthz and /metrics (overrides health.port; 0 = any free port)")
    parser.add_argument("--summary", type=Path, default=None, metavar="JSON",
                        help="write the drop ledger and run statistics here at exit")


def _raise_stopped(signum: int, _first: bool) -> None:
    """StopSignals' callback while the camera is prepared: Stopped ends that blocking call (serve() later polls
    its own StopSignals instead)."""
    raise Stopped(signal.Signals(signum).name)


def main(args: argparse.Namespace) -> int:
    from tofd.config import load_config, override
    from tofd.outputs import check_output_file
    from tofd.process_setup import prepare_service_process
    from tofd.service.camera import open_camera
    from tofd.service.daemon import parse_rerun_spec, serve
    from tofd.service.pipeline.queues import run_policy
    from tofd.service.signals import StopSignals

    cfg = parse_foxglove_spec(args.foxglove, parse_rerun_spec(args.rerun, load_config(args.config)))
    cfg = replace(cfg, camera=arguments.camera_config(cfg.camera, args))
    if args.health_port is not None:
        cfg = override(cfg, "health", "--health-port", port=args.health_port)
    if args.summary is not None:
        check_output_file(args.summary, "--summary")
    policy = run_policy(cfg.pipeline.policy, live_source=True)
    try:
        with StopSignals(_raise_stopped):
            camera = open_camera(cfg, args.emulate)
    except Stopped as exc:
        print(f"tofd run: {exc} before the camera was ready; stopped", file=sys.stderr)
        return 0
    if camera.intrinsics is not None:  # the device's own calibration (an SDK camera's), for the workers' plans
        cfg = replace(cfg, intrinsics=camera.intrinsics)
    prepare_service_process()
    with camera:
        result = serve(cfg, camera, policy, live_source=True, max_frames=args.frames, summary_path=args.summary)
    s = result.summary
    by_stage = ", ".join(f"{stage} {n}" for stage, n in s["dropped_by_stage"].items())
    print(f"tofd run: frames in {s['frames_in']}, out {s['frames_out']}, dropped {s['frames_dropped']}"
          + (f" ({by_stage})" if by_stage else "") + f", device gaps {s['device_gaps']}, {s['fps']} fps"
          + (f"; error: {s['error']}" if s["error"] else ""), file=sys.stderr)
    return result.exit_code
