"""Replay a recording through the pipeline: writes an .rrd and per-frame results (JSON Lines) to --out.

Lossless by default (every frame is processed, as fast as the pipeline goes, with a progress bar on
stderr); --realtime replays at the recorded pace (times --speed), skipping frames it cannot keep up with.
Output in --out: <stem>.rrd (open it with `rerun <stem>.rrd`), <stem>.results.jsonl (frame counter, nose pixel
and 3-D point, score, the nose track beside it, stage timings in ms; with --loop also the loop index),
<stem>.summary.json (drop ledger, fps, p50/p99 timings, track counts, model path and SHA-256). A recording with
ground truth also gets an accuracy line (detection and track) and <stem>.accuracy.png (nose error and score over
frames). --rerun adds or replaces the viewer sink; --foxglove HOST:PORT streams the replay to Foxglove as well, at the
recorded pace.
--check GOLDEN compares the per-frame results with a golden file (docs/BATCH.md) and exits 1 on a regression.
Inputs are recognised by content (tofd.drivers.opener): a ROS 1 or ROS 2 bag is imported to a temporary recording first
(as `tofd import` does, with the same options); an Azure Kinect / Orbbec Femto .mkv is read directly, or imported
first for --realtime, --foxglove, --loop and --seek.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from tofd import arguments
from tofd.config import Config
from tofd.service.daemon import RERUN_SPEC_HELP
from tofd.service.foxglove.spec import FOXGLOVE_SPEC_HELP, parse_foxglove_spec

if TYPE_CHECKING:
    from tofd.drivers.intrinsics import Intrinsics
    from tofd.drivers.source import FrameSource, Rejected

log = logging.getLogger(__name__)

EXIT_AT_ONCE = True  # tofd.cli.main: no interpreter teardown after the service returns (the SIGTERM bound)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="recording made by `tofd record` (e.g. replay_data/*.mcap), a "
                                                "ROS 1 or ROS 2 bag, imported on the fly (see `tofd import`), or an "
                                                "Azure Kinect / Orbbec Femto .mkv")
    parser.add_argument("--out", type=Path, default=Path("replay_out"), help="output directory (default: %(default)s)")
    parser.add_argument("--config", type=Path, default=None, help="config file (default: the bundled tofd.toml)")
    parser.add_argument("--realtime", action="store_true", help="replay at the recorded frame rate")
    parser.add_argument("--speed", type=arguments.positive_float, default=None,
                        help="realtime speed factor (default 1; needs --realtime)")
    parser.add_argument("--seek", type=arguments.frame_counter, default=None, metavar="N",
                        help="start at frame counter N")
    parser.add_argument("--loop", action="store_true", help="replay again from the start until interrupted")
    parser.add_argument("--frames", type=arguments.positive_int, default=None, metavar="N", help="stop after N frames")
    parser.add_argument("--rerun", default=None, metavar="SINK",
                        help=f"{RERUN_SPEC_HELP}; default: save:OUT/<stem>.rrd")
    parser.add_argument("--foxglove", default=None, metavar="HOST:PORT",
                        help=f"{FOXGLOVE_SPEC_HELP}; the replay then runs at the recorded pace (--realtime)")
    parser.add_argument("--check", type=Path, default=None, metavar="GOLDEN",
                        help="compare the per-frame results with this golden file; exit 1 on a regression")
    parser.add_argument("--write-golden", type=Path, default=None, metavar="GOLDEN",
                        help="write the per-frame results as a golden file (e.g. replay_data/<stem>.golden.json)")
    arguments.add_bag_arguments(parser)


def _report_accuracy(results: Path, plot: Path) -> None:
    """Print the accuracy line and write the plot when the recording carries ground truth."""
    from tofd.lab.accuracy import accuracy_from_results, accuracy_table, plot_accuracy

    acc = accuracy_from_results(results)
    if acc is not None:
        plot_accuracy(acc, plot)
        print(f"tofd replay: {acc.line()}; plot {plot}", file=sys.stderr)
        if acc.distance_m is not None:
            print(accuracy_table(acc.to_dict()), file=sys.stderr)


def main(args: argparse.Namespace) -> int:
    from tofd.errors import UsageError
    from tofd.inputs import convert, open_reader
    from tofd.progress import Progress

    if args.speed is not None and not (args.realtime or args.foxglove not in (None, "none")):
        raise UsageError("--speed needs --realtime (a lossless replay runs as fast as the pipeline goes)")
    stem = args.file.name.split(".")[0]
    options = arguments.bag_options(args)
    fmt, source = open_reader(args.file, options)
    if fmt.read_as == "recording":  # replayed by a source with the replay's pace, loop and seek
        source.close()
        return _replay(args, args.file, stem)
    if fmt.read_as == "source" and not (args.realtime or args.foxglove not in (None, "none") or args.loop
                                        or args.seek is not None):
        return _replay_source(args, source, stem)
    import tempfile

    with tempfile.TemporaryDirectory(prefix="tofd-replay-") as tmp:
        recording = Path(tmp) / f"{stem}.mcap"
        rejected: list[Rejected] = []
        done = convert(args.file, fmt, source, options, recording, lambda total: Progress("replay: import", total),
                       rejected)
        print(f"tofd replay: imported {done} from {args.file}", file=sys.stderr)
        return _replay(args, recording, stem, rejected)


def _replay(args: argparse.Namespace, recording: Path, stem: str, rejected: list[Rejected] | None = None) -> int:
    """Replay the tofd recording `recording` (args.file, or the recording a bag was imported to, with the frames
    its import rejected ledgered after its own)."""
    from tofd.config import load_config
    from tofd.drivers.bags.source import RejectsAfter
    from tofd.errors import UsageError
    from tofd.inputs import open_recording

    cfg = _replay_config(args, load_config(args.config), stem)
    realtime = args.realtime or (args.foxglove is not None and cfg.foxglove.enabled)  # someone watches it live
    replay, info = open_recording(recording, mode="realtime" if realtime else "lossless", speed=args.speed or 1.0,
                                  loop=args.loop, seek=args.seek)
    if args.seek is not None:
        reached, last = replay.counters_reach(args.seek)
        if not reached:
            raise UsageError(f"{args.file}: --seek {args.seek}: past the end (last frame counter {last})")
    source: FrameSource = RejectsAfter(replay, rejected) if rejected else replay
    return _serve(args, cfg, source, info.intrinsics, args.frames or (None if args.loop else info.frame_count), stem)


def _replay_source(args: argparse.Namespace, source: FrameSource, stem: str) -> int:
    """Replay `source`, a file a FrameSource reads directly (tofd.drivers.opener), lossless, from its first frame:
    its lost frames are ledgered as the pipeline meets them."""
    from tofd.config import load_config

    try:
        cfg = _replay_config(args, load_config(args.config), stem)
    except BaseException:
        source.close()
        raise
    return _serve(args, cfg, source, source.intrinsics, args.frames, stem)


def _replay_config(args: argparse.Namespace, cfg: Config, stem: str) -> Config:
    from tofd.service.daemon import parse_rerun_spec

    cfg = parse_foxglove_spec(args.foxglove, cfg)
    cfg = parse_rerun_spec(args.rerun or f"save:{args.out / (stem + '.rrd')}", cfg)
    return replace(cfg, health=replace(cfg.health, enabled=False))


def _serve(args: argparse.Namespace, cfg: Config, source: FrameSource, intrinsics: Intrinsics | None,
           total: int | None, stem: str) -> int:
    """Run the pipeline over `source` and write the outputs, saying where a damaged file stopped (its report)."""
    from tofd.batch.golden import GoldenRecorder, golden_check
    from tofd.outputs import prepare_output_dir
    from tofd.process_setup import prepare_service_process
    from tofd.progress import Progress
    from tofd.service.daemon import serve
    from tofd.service.pipeline import ResultsWriter
    from tofd.service.pipeline.queues import run_policy

    policy = run_policy(cfg.pipeline.policy, live_source=False)
    out = prepare_output_dir(args.out)
    if intrinsics is not None:
        cfg = replace(cfg, intrinsics=intrinsics)
    results_path = out / f"{stem}.results.jsonl"
    writer = ResultsWriter(results_path, loops=args.loop)
    golden = GoldenRecorder() if args.check or args.write_golden else None
    prepare_service_process()
    try:
        with source:
            result = serve(cfg, source, policy, live_source=False, writers=(writer,) + ((golden,) if golden else ()),
                           writers_read_maps=golden is not None, max_frames=args.frames,
                           progress=Progress("replay", total), summary_path=out / f"{stem}.summary.json")
    except BaseException:  # a TofdError or OSError is one line and exit status 1 (tofd.cli)
        writer.discard()
        raise
    s = result.summary
    try:
        writer.close()
    except OSError as exc:
        s["outputs_failed"][str(results_path)] = exc.strerror or str(exc)
        print(f"tofd replay: output {results_path} failed: {exc.strerror or exc}", file=sys.stderr)
    if source.report.stopped_early:
        print(f"tofd replay: the recording is {source.report.line()}", file=sys.stderr)
    failed = s["outputs_failed"]  # each said so in one line when it failed
    if str(results_path) not in failed:
        _report_accuracy(results_path, out / f"{stem}.accuracy.png")
    outputs = {"results.jsonl": results_path, "summary.json": out / f"{stem}.summary.json"}
    if cfg.rerun.sink == "save":
        outputs["rrd"] = Path(cfg.rerun.path)
    written = [name for name, path in outputs.items() if str(path) not in failed and path == out / f"{stem}.{name}"]
    elsewhere = [str(path) for name, path in outputs.items() if str(path) not in failed and name not in written]
    not_written = [name for name, path in outputs.items() if str(path) in failed]
    skipped = source.counters["replay_dropped"]
    loops = source.counters["replay_loops"]
    reason = str(s["shutdown"]["reason"])
    stopped_by = reason if reason.startswith("SIG") else None
    print(f"tofd replay: {s['frames_out']} frames processed, {s['frames_dropped']} dropped"
          + (f", {skipped} skipped to keep the recorded pace" if skipped else "")
          + (f", {loops + 1} passes" if args.loop else "")
          + f", {s['fps']} fps; wrote " + (f"{out}/{stem}.{{{','.join(written)}}}" if written else "nothing")
          + "".join(f" and {path}" for path in elsewhere)
          + (f"; failed: {', '.join(not_written)}" if not_written else ""), file=sys.stderr)
    if stopped_by:  # the outputs hold what was done; no golden check of a part
        print(f"tofd replay: interrupted by {stopped_by} after {s['frames_out']}"
              + (f" of {total}" if total is not None else "") + " frames", file=sys.stderr)
        return 128 + signal.Signals[stopped_by].value
    code = 1 if failed else result.exit_code
    if golden is not None:
        regression, lines = golden_check(golden.rows, stem, cfg, result.model, args.write_golden, args.check)
        for line in lines:
            print(line if line.startswith("  ") else f"tofd replay: {line}", file=sys.stderr)
        return 1 if regression else code
    return code
