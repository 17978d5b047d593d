"""Replay a recording through the pipeline: writes an .rrd and per-frame results (JSON Lines) to --out.

Lossless by default (every frame is processed, as fast as the pipeline goes, with a progress bar on
stderr); --realtime replays at the recorded pace (times --speed). Output in --out: <stem>.rrd (open it with
`rerun <stem>.rrd`), <stem>.results.jsonl (frame counter, nose pixel and 3-D point, score, stage timings
in ms), <stem>.summary.json (drop ledger, fps, p50/p99 timings). --rerun adds or replaces the viewer sink.
--check GOLDEN compares the per-frame results with a golden file (docs/BATCH.md) and exits 1 on a regression.
"""

from __future__ import annotations

import argparse
import logging
import sys
from dataclasses import replace
from pathlib import Path

from tofd.config import Config
from tofd.service.daemon import RERUN_SPEC_HELP


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="recording made by `tofd record` (e.g. replay_data/*.mcap)")
    parser.add_argument("--out", type=Path, default=Path("replay_out"), help="output directory (default: %(default)s)")
    parser.add_argument("--config", type=Path, default=None, help="config file (default: config/tofd.toml)")
    parser.add_argument("--realtime", action="store_true", help="replay at the recorded frame rate")
    parser.add_argument("--speed", type=float, default=1.0, help="realtime speed factor (default: %(default)s)")
    parser.add_argument("--seek", type=int, default=None, metavar="N", help="start at frame counter N")
    parser.add_argument("--loop", action="store_true", help="replay again from the start until interrupted")
    parser.add_argument("--frames", type=int, default=None, metavar="N", help="stop after N frames")
    parser.add_argument("--rerun", default=None, metavar="SINK",
                        help=f"{RERUN_SPEC_HELP}; default: save:OUT/<stem>.rrd")
    parser.add_argument("--check", type=Path, default=None, metavar="GOLDEN",
                        help="compare the per-frame results with this golden file; exit 1 on a regression")
    parser.add_argument("--write-golden", type=Path, default=None, metavar="GOLDEN",
                        help="write the per-frame results as a golden file (e.g. replay_data/<stem>.golden.json)")


def main(args: argparse.Namespace) -> int:
    from drivers.recording.replay import ReplaySource, read_recording_info
    from drivers.source import DriverError
    from tofd.batch.golden import GoldenRecorder
    from tofd.config import load_config
    from tofd.service.daemon import Progress, parse_rerun_spec, serve
    from tofd.service.pipeline import PipelineError, ResultsWriter
    from tofd.service.viewer import ViewerError

    logging.basicConfig(level=logging.INFO, format="tofd: %(message)s")
    stem = args.file.name.split(".")[0]
    cfg = load_config(args.config)
    cfg = parse_rerun_spec(args.rerun or f"save:{args.out / (stem + '.rrd')}", cfg)
    cfg = replace(cfg, health=replace(cfg.health, enabled=False))
    policy = "lossless" if cfg.pipeline.policy == "auto" else cfg.pipeline.policy
    try:
        info = read_recording_info(args.file)
        source = ReplaySource(args.file, mode="realtime" if args.realtime else "lossless", speed=args.speed,
                              loop=args.loop, seek=args.seek)
    except (DriverError, OSError, ValueError) as exc:
        print(f"tofd replay: {args.file}: {exc}", file=sys.stderr)
        return 2
    if info.intrinsics is not None:
        cfg = replace(cfg, intrinsics=info.intrinsics)
    total = args.frames or (None if args.loop else info.frame_count)
    writer = ResultsWriter(args.out / f"{stem}.results.jsonl")
    golden = GoldenRecorder() if args.check or args.write_golden else None
    try:
        with source:
            result = serve(cfg, source, policy, live_source=False, writers=(writer,) + ((golden,) if golden else ()),
                           max_frames=args.frames,
                           progress=Progress(total, "replay"), summary_path=args.out / f"{stem}.summary.json")
    except (DriverError, PipelineError, ViewerError, OSError) as exc:
        print(f"tofd replay: {exc}", file=sys.stderr)
        return 1
    finally:
        writer.close()
    s = result.summary
    if source.stopped_reason not in (None, "end"):
        print(f"tofd replay: the recording is {source.stopped_reason} after frame {source.last_good_counter}: "
              f"{source.stop_detail}", file=sys.stderr)
    written = ["results.jsonl", "summary.json"] + (["rrd"] if cfg.rerun.sink == "save" else [])
    print(f"tofd replay: {s['frames_out']} frames processed, {s['frames_dropped']} dropped, {s['fps']} fps; "
          f"wrote {args.out}/{stem}.{{{','.join(written)}}}", file=sys.stderr)
    if golden is not None:
        return check_golden(args, golden.rows, stem, cfg) or result.exit_code
    return result.exit_code


def check_golden(args: argparse.Namespace, rows: list[dict], stem: str, cfg: Config) -> int:
    """Write and/or check the golden file; 1 (with the differences on stderr) on a regression."""
    from tofd.batch.golden import compare, golden_document, load_golden, write_golden

    doc = golden_document(rows, stem, cfg)
    if args.write_golden:
        write_golden(args.write_golden, doc)
        print(f"tofd replay: wrote golden file {args.write_golden} ({len(rows)} frames)", file=sys.stderr)
    if not args.check:
        return 0
    try:
        golden = load_golden(args.check)
    except ValueError as exc:
        print(f"tofd replay: {exc}", file=sys.stderr)
        return 2
    problems, notes = compare(golden, rows)
    notes += [f"the golden file was made with {k} {v[:12]}, this run has {doc['digests'][k][:12]}"
              for k, v in golden.get("digests", {}).items() if k != "run" and v != doc["digests"].get(k)]
    for line in notes:
        print(f"tofd replay: check: {line}", file=sys.stderr)
    if problems:
        print(f"tofd replay: check FAILED against {args.check}:", file=sys.stderr)
        for line in problems:
            print(f"  {line}", file=sys.stderr)
        return 1
    print(f"tofd replay: check passed against {args.check} ({len(rows)} frames)", file=sys.stderr)
    return 0
