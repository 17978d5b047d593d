"""Run the live service: attach to the camera, process frames, stream to Rerun, serve /healthz and /metrics.

--foxglove HOST:PORT also serves the live stream to Foxglove (its WebSocket protocol; 127.0.0.1 by default).
Attaches to the camera with the configured serial (or --serial, else the first one found), or to the
emulated camera with --emulate. Live queues are latest-wins: when processing falls behind, the oldest
frames are dropped and counted in the drop ledger. SIGTERM/SIGINT drain the queues and exit 0 (also while
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
    parser.add_argument("--serial", type=arguments.serial, default=None,
                        help="camera serial number (8 hex digits; overrides the config)")
    parser.add_argument("--rerun", default=None, metavar="SINK", help=RERUN_SPEC_HELP)
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
    from tofd.drivers.source import DriverError
    from tofd.outputs import check_output_file
    from tofd.process_setup import prepare_service_process
    from tofd.service.camera import open_camera
    from tofd.service.daemon import parse_rerun_spec, serve
    from tofd.service.pipeline import PipelineError
    from tofd.service.pipeline.queues import run_policy
    from tofd.service.signals import StopSignals
    from tofd.service.viewer import ViewerError

    cfg = parse_foxglove_spec(args.foxglove, parse_rerun_spec(args.rerun, load_config(args.config)))
    if args.serial is not None:
        cfg = replace(cfg, camera=replace(cfg.camera, serial=args.serial))
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
    except (DriverError, OSError) as exc:
        print(f"tofd run: {exc}", file=sys.stderr)
        return 1
    prepare_service_process()
    try:
        with camera:
            result = serve(cfg, camera, policy, live_source=True, max_frames=args.frames,
                           summary_path=args.summary)
    except (DriverError, PipelineError, ViewerError, OSError) as exc:
        print(f"tofd run: {exc}", file=sys.stderr)
        return 1
    s = result.summary
    by_stage = ", ".join(f"{stage} {n}" for stage, n in s["dropped_by_stage"].items())
    print(f"tofd run: frames in {s['frames_in']}, out {s['frames_out']}, dropped {s['frames_dropped']}"
          + (f" ({by_stage})" if by_stage else "") + f", device gaps {s['device_gaps']}, {s['fps']} fps"
          + (f"; error: {s['error']}" if s["error"] else ""), file=sys.stderr)
    return result.exit_code
