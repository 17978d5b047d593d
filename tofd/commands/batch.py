"""Re-process recordings and datasets on Dask: per-frame results as Parquet, partitioned by input, and a summary.

INPUTS are recordings (.mcap), dataset files (.npz, as `tofd dataset generate` writes them), Azure Kinect / Orbbec
Femto recordings (.mkv), RealSense / Orbbec SDK recordings and camera drivers' ROS bags (.bag, .db3; a local file
named otherwise is recognised by its content), directories (searched for these) or glob patterns, local or fsspec
URLs. Each input is cut into partitions of --partition-frames frames, read by the tasks (a recording through its
index, a dataset by frame range, an .mkv or a bag whole). Output in --out:
recording=<name>/part-<first>-<stop>-<key>.parquet (key: digests of input, partition, config, model, tofd version),
a Hive-partitioned Parquet dataset that pyarrow, DuckDB and Spark open as it is, and _summary.json (frames
in/out/dropped with reasons, stage times, throughput, digests, and where the inputs carry ground truth the nose
accuracy overall and per distance and `tofd evaluate`'s tables of the model's variants).
Default: a LocalCluster of --workers processes; --scheduler tcp://host:8786 uses an existing Dask cluster.
"""

from __future__ import annotations

import argparse
import os


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="recording, dataset .npz, directory, glob or fsspec URL")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory (local path or fsspec URL)")
    parser.add_argument("--config", default=None, help="config file (default: config/tofd.toml)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="Dask scheduler address, e.g. tcp://host:8786 (default: a local cluster)")
    parser.add_argument("--workers", type=int, default=min(os.cpu_count() or 1, 8),
                        help="worker processes of the local cluster (default: %(default)s)")
    parser.add_argument("--partition-frames", type=int, default=150, metavar="N",
                        help="frames per partition (default: %(default)s, 5 s at 30 fps)")
    parser.add_argument("--resume", action="store_true", help="skip partitions whose results already exist")
    parser.add_argument("--no-evaluation", dest="evaluation", action="store_false",
                        help="skip evaluating the model's variants on frames with ground truth (no eval_* columns)")
    parser.add_argument("--retries", type=int, default=2, help="retries of a failing task (default: %(default)s)")


def main(args: argparse.Namespace) -> int:
    import sys

    from tofd.batch.runner import SUMMARY_NAME, RunOptions, batch_client, prepare, run_plan
    from tofd.config import load_config
    from tofd.errors import UsageError
    from tofd.lab.accuracy import accuracy_table

    if args.workers < 1:
        raise UsageError(f"--workers: expected >= 1, got {args.workers}")
    cfg = load_config(args.config)
    inputs, job, digests = prepare(args.inputs, args.out, cfg, args.partition_frames, args.evaluation)
    for inp in inputs:
        if inp.error:
            print(f"tofd batch: {inp.url}: {inp.error}", file=sys.stderr)
    if not any(inp.partitions for inp in inputs):
        raise UsageError("no input can be processed")  # every input is missing, empty or unreadable
    with batch_client(args.scheduler, args.workers) as client:
        summary = run_plan(client, inputs, job, args.out, digests, RunOptions(args.resume, args.retries))
    bad = [e for e in summary["inputs"] if e["status"] != "ok"]
    for e in bad:
        print(f"tofd batch: {e['input']}: {e['status']}: {'; '.join(e['errors'][:3])}", file=sys.stderr)
    if summary["evaluation"] is not None:
        print(f"tofd batch: {summary['evaluation']['line']}", file=sys.stderr)
        print(accuracy_table(summary["evaluation"]), file=sys.stderr)
    if summary["variant_evaluation"] is not None:
        print(summary["variant_evaluation"]["table"], file=sys.stderr)
    p = summary["partitions"]
    print(f"tofd batch: {summary['frames_out']} frames processed, {summary['frames_dropped']} dropped, "
          f"{p['computed']} partitions computed, {p['resumed']} resumed, {p['failed']} failed; "
          + (f"{summary['throughput_fps']} frames/s" if summary["throughput_fps"] is not None else "nothing computed")
          + f"; wrote {args.out}/{SUMMARY_NAME}", file=sys.stderr)
    return 1 if bad else 0
