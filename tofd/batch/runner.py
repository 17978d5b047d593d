"""Running a batch plan on Dask: a LocalCluster of worker processes by default, or an existing scheduler; one
task per partition (only its small JSON description goes through the scheduler, the frames are read by the
task from storage); a summary of the run.

A task whose worker dies (kill -9, out of memory) is rescheduled by Dask on another worker (`retries` more
times for errors raised in the task); the result of a partition does not depend on where or how often it ran.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import logging
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import dask
import fsspec
import numpy as np
import pyarrow.parquet as pq
from distributed import Client, LocalCluster, as_completed

from tofd.algorithm.detector import Margin, NoseModel
from tofd.batch.plan import InputPlan, Partition, expand_inputs, plan_inputs, run_digests
from tofd.batch.rows import TIMED, minima_from_rows, rows_digest
from tofd.batch.task import PrepareWorker, partition_stats, run_partition
from tofd.config import Config, config_from_dict, config_table
from tofd.errors import UsageError
from tofd.lab.accuracy import accuracy_from_records
from tofd.lab.evaluation import variant_results
from tofd.lab.report import answers_table, eer_table, results_to_dict
from tofd.process_setup import THREAD_ENV
from tofd.progress import Progress
from tofd.service.model import load_service_model

log = logging.getLogger(__name__)

SUMMARY_NAME = "_summary.json"  # "_": dataset readers (pyarrow, Spark) skip it; only Parquet parts are data
CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "1s",
                  "distributed.worker.memory.monitor-interval": "1s", "distributed.admin.system-monitor.interval": "2s"}
"""Dask settings of the local cluster: no statistical profiler (it samples the running task's stack every 10 ms),
and the event-loop watchdog and resource monitors every 1-2 s instead of every 20-500 ms, so that the scheduler,
nannies and workers use next to no CPU beside the tasks; an existing cluster's workers take them from their
environment (docs/BATCH.md)."""


@contextlib.contextmanager
def batch_client(scheduler: str | None, workers: int) -> Iterator[Client]:
    """A Dask client: of the scheduler at `scheduler` (tcp://host:8786), else of a new LocalCluster of `workers`
    single-threaded worker processes (with the dashboard when bokeh is installed); Dask's own INFO lines are not
    shown unless tofd logs at debug level."""
    if logging.getLogger().level > logging.DEBUG:  # Dask's INFO lines only when tofd logs at debug level
        logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    # the scheduler's HTTP server (and the dashboard, with bokeh) on loopback, any free port: Dask's default is
    # port 8787 on every interface
    dashboard = "127.0.0.1:0"
    with dask.config.set(CLUSTER_CONFIG), LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=dashboard,
            env=THREAD_ENV) as cluster, Client(cluster) as client:
        yield client


@dataclass(slots=True)
class RunOptions:
    resume: bool = False
    retries: int = 2
    progress: bool = True


def run_plan(client: Client, inputs: list[InputPlan], job: dict, out: str, digests: dict[str, str],
             options: RunOptions, on_done: Callable[[Client, dict], None] | None = None) -> dict:
    """Process every partition of `inputs` (job: prepare's); write and return
    the summary. on_done(client, stats) is called after each finished partition (tests use it)."""
    t_start = time.perf_counter()
    parts = [p for inp in inputs for p in inp.partitions]
    done: dict[str, dict] = {}
    if options.resume:
        for p in parts:
            stats = partition_stats(p.output)
            if stats is not None:
                done[p.output] = {**stats, "resumed": True}
    todo = [p for p in parts if p.output not in done]
    failed: dict[str, str] = {}
    total = sum(p.frames for p in parts)
    progress = Progress("batch", total) if options.progress else None
    count = sum(s["frames_in"] for s in done.values())
    dashboard = getattr(client, "dashboard_link", None) if importlib.util.find_spec("bokeh") else None
    if dashboard and options.progress:
        log.info("Dask dashboard: %s", dashboard)
    t_setup = time.perf_counter()
    if todo:
        client.register_plugin(PrepareWorker())
    setup_s = time.perf_counter() - t_setup
    # the job (config and model, a few kB) goes with each task: a broadcast scatter can wait forever on a worker
    # that is still starting or has just died (dask/distributed#4907)
    job_json = json.dumps(job)
    futures = {client.submit(run_partition, p.to_json(), job_json, key=f"tofd-batch-{_key(p)}",
                             retries=options.retries, pure=False): p for p in todo}
    t_submit = time.perf_counter()
    for future in as_completed(futures):
        p = futures[future]
        try:
            stats = future.result()
        except Exception as exc:  # noqa: BLE001 (a partition that cannot be done is reported, the rest go on)
            failed[p.output] = f"{type(exc).__name__}: {exc}"
            count += p.frames
        else:
            done[p.output] = stats
            count += stats["frames_in"]
            if on_done is not None:
                on_done(client, stats)
        if progress is not None:
            progress.update(count)
    wall_s = time.perf_counter() - t_start
    if progress is not None:
        progress.done()
    _remove_partial_files(parts)
    summary = _summary(inputs, done, failed, digests, out, wall_s, time.perf_counter() - t_submit,
                       setup_s, n_workers=len(client.scheduler_info().get("workers", {})), dashboard=dashboard,
                       model=None if job["model"] is None else NoseModel.from_dict(job["model"]),
                       margin=Margin.from_config(config_from_dict(job["config"]).detector))
    fs, path = fsspec.core.url_to_fs(out)
    fs.makedirs(path, exist_ok=True)
    with fs.open(f"{path}/{SUMMARY_NAME}", "w") as fh:
        json.dump(summary, fh, indent=2)
    return summary


def _remove_partial_files(parts: list[Partition]) -> None:
    """Delete the temporary files of tasks whose worker died while writing (each retry writes its own)."""
    for directory in {p.output.rsplit("/", 1)[0] for p in parts}:
        fs, path = fsspec.core.url_to_fs(directory)
        for tmp in fs.glob(f"{path}/.part-*.parquet.tmp-*"):
            fs.rm(tmp)


def _key(p: Partition) -> str:
    return p.output.rsplit("/", 2)[-2].split("=", 1)[-1] + "-" + p.output.rsplit("-", 1)[-1].split(".")[0]


def read_rows(outputs: list[str], columns: list[str] | None = None) -> list[dict]:
    """The rows of partition files, in the given order."""
    rows: list[dict] = []
    for output in outputs:
        with fsspec.open(output, "rb") as fh:
            rows.extend(pq.read_table(fh, columns=columns).to_pylist())
    return rows


def _percentiles(values: list[float]) -> dict[str, float]:
    a = np.asarray([v for v in values if v is not None], dtype=float)
    if a.size == 0:
        return {}
    return {"mean": round(float(a.mean()), 3), "p50": round(float(np.percentile(a, 50)), 3),
            "p99": round(float(np.percentile(a, 99)), 3)}


def _summary(inputs: list[InputPlan], done: dict[str, dict], failed: dict[str, str], digests: dict[str, str],
             out: str, wall_s: float, run_s: float, setup_s: float, n_workers: int, dashboard: str | None,
             model: NoseModel | None, margin: Margin) -> dict:
    dropped: Counter = Counter()
    per_input = []
    all_rows: list[dict] = []
    for inp in inputs:
        entry: dict = {"input": inp.url, "recording": inp.recording, "indexed": inp.indexed,
                       "partitions": len(inp.partitions), "frames_in": 0, "frames_out": 0, "errors": []}
        if inp.error:
            entry["errors"].append(inp.error)
        outputs = []
        for p in inp.partitions:
            if p.output in failed:
                entry["errors"].append(f"partition {p.first}-{p.stop}: {failed[p.output]}")
                if p.frames:
                    dropped["partition failed"] += p.frames
                continue
            s = done[p.output]
            entry["frames_in"] += s["frames_in"]
            entry["frames_out"] += s["frames_out"]
            dropped.update(s["dropped"])
            entry["errors"].extend(s["errors"])
            outputs.append(p.output)
        rows = read_rows(outputs)
        entry["results_digest"] = rows_digest(rows)
        input_accuracy = accuracy_from_records(rows)
        entry["accuracy"] = None if input_accuracy is None else input_accuracy.line()
        entry["parts"] = [o[len(out.rstrip("/")) + 1:] for o in outputs]
        entry["status"] = "ok" if not entry["errors"] else ("partial" if entry["frames_out"] else "failed")
        all_rows.extend(rows)
        per_input.append(entry)
    accuracy = accuracy_from_records(all_rows)
    computed = [s for s in done.values() if not s.get("resumed")]
    frames_done = sum(s["frames_out"] for s in computed)
    n = max(len(computed), 1)
    per_part = {k: round(sum(s[f"{k}_ms"] for s in computed) / n, 2) for k in ("setup", "read", "compute", "write")}
    task_ms = sum(s["task_ms"] for s in computed) / n
    # time a worker slot spent per partition beyond the task itself: scheduling, transfer, result handling
    per_part["scheduling"] = round(max(0.0, run_s * 1e3 * n_workers / n - task_ms), 2) if computed else 0.0
    per_part["cpu"] = round(sum(s["cpu_ms"] for s in computed) / n, 2)  # the task thread's CPU time
    return {
        "inputs": per_input,
        "frames_in": sum(e["frames_in"] for e in per_input),
        "frames_out": sum(e["frames_out"] for e in per_input),
        "frames_dropped": sum(dropped.values()),
        "dropped_reasons": dict(sorted(dropped.items())),
        "partitions": {"total": sum(len(i.partitions) for i in inputs), "computed": len(computed),
                       "resumed": len(done) - len(computed), "failed": len(failed)},
        "stage_ms": {stage: _percentiles([r[f"t_{stage}_ms"] for r in all_rows]) for stage in TIMED},
        "per_partition_ms": per_part,
        "wall_s": round(wall_s, 3),
        "worker_setup_s": round(setup_s, 3),
        "throughput_fps": round(frames_done / run_s, 2) if computed and run_s > 0 else None,
        "task_cpu_ms_per_frame": round(sum(s["cpu_ms"] for s in computed) / frames_done, 2) if frames_done else None,
        "workers": n_workers,
        "dashboard": dashboard,
        "digests": digests,
        "results_digest": rows_digest(all_rows),
        "evaluation": None if accuracy is None else accuracy.to_dict(),
        "variant_evaluation": variant_evaluation(all_rows, model, margin),
    }


def variant_evaluation(rows: list[dict], model: NoseModel | None, margin: Margin) -> dict | None:
    """`tofd evaluate`'s results of the model's variants over the rows with eval_* columns (frames with ground
    truth; answers with the detector's `margin` test): frames, its EER and answers tables as text, and per variant
    the EERs and answers overall and per distance bin (without the ROC points); None without a model or such rows."""
    if model is None:
        return None
    minima, distance_m = minima_from_rows(rows, list(model.variants))
    if not len(distance_m):
        return None
    results = variant_results(model, minima, distance_m, margin)
    return {"frames": len(distance_m), "table": f"{eer_table(results)}\n{answers_table(results)}",
            "results": results_to_dict(results, points=False)}


def prepare(items: list[str], out: str, cfg: Config, partition_frames: int,
            evaluation: bool = True) -> tuple[list[InputPlan], dict, dict]:
    """The inputs (with their partitions or errors), the job every task gets (config table, model, whether to
    evaluate the model on frames with ground truth) and the run's digests, for the service config `cfg` and its
    detector model."""
    if partition_frames < 1:
        raise UsageError(f"partition size: expected >= 1 frames, got {partition_frames}")
    model = load_service_model(cfg)
    table, model_dict = config_table(cfg), None if model is None else model.to_dict()
    job = {"config": table, "model": model_dict, "evaluation": evaluation}
    digests = run_digests(table, model_dict, evaluation)
    inputs = expand_inputs(items)
    plan_inputs(inputs, out, digests["run"], partition_frames)
    return inputs, job, digests
