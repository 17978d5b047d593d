"""One batch task, run on a Dask worker: read a partition's frames from storage, process each with the pipeline
workers' per-frame code (tofd.service.pipeline.stages.process_frame), evaluate the model's variants on each frame
with ground truth as `tofd evaluate` does (FrameEvaluation), write the rows as one Parquet file.

The file is written under a temporary name and renamed, so it exists only complete; its schema metadata holds
the partition's statistics (key b"tofd.partition", JSON) for --resume and the summary.
"""

from __future__ import annotations

import json
import os
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import replace

import fsspec
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from distributed.diagnostics.plugin import WorkerPlugin

from tofd.algorithm.detector import Candidates, NoseModel
from tofd.algorithm.extract import FeatureExtractor
from tofd.batch.plan import Partition
from tofd.batch.rows import ROW_SCHEMA, eval_columns, frame_row
from tofd.config import Config, config_from_dict
from tofd.drivers.frame import Frame
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.recording.index import FrameIndex, read_chunks
from tofd.lab.dataset import DatasetFile
from tofd.lab.evaluation import NOSE_RADIUS_M, frame_samples, image_minima
from tofd.process_setup import prepare_compute_process
from tofd.service.pipeline.slots import local_slot
from tofd.service.pipeline.stages import FeatureStage, process_frame

STATS_KEY = b"tofd.partition"


class PrepareWorker(WorkerPlugin):
    """Dask worker plugin: prepare_process on every worker, those running when it is registered and those that
    join or restart later, so a worker's first partition does not pay for imports and set-up."""

    name = "tofd-batch-prepare"

    def setup(self, worker: object) -> None:
        prepare_process()


def prepare_process() -> None:
    """Make this process ready to run partitions (idempotent): tofd.process_setup.prepare_compute_process, as
    the pipeline workers."""
    global _prepared
    if not _prepared:
        prepare_compute_process()
        _prepared = True


_prepared = False


def _frames(part: Partition, stats: dict, errors: list[str]) -> Iterator[tuple[Frame, float]]:
    """The partition's frames with the ms spent reading each; damaged chunks are counted and skipped."""
    if part.dataset:
        yield from _dataset_frames(part, stats, errors)
        return
    if not part.offsets:  # no index, or a file a FrameSource reads: the whole file, sequentially
        from tofd.drivers.opener import open_input
        from tofd.drivers.source import DriverError

        t0 = time.perf_counter()
        try:
            _, source = open_input(part.url)
        except (DriverError, OSError, ValueError) as exc:
            errors.append(str(exc))
            return
        with source:
            for frame in source:
                stats["frames_in"] += 1
                yield frame, (time.perf_counter() - t0) * 1e3
                t0 = time.perf_counter()
            lost = source.take_rejected()
            if lost:
                frames = sum(r.frames for r in lost)
                stats["frames_in"] += frames
                stats["dropped"]["damaged"] += frames
                errors.append(f"{frames} frames lost or damaged, the first: {lost[0].reason}")
            if source.report.stopped_early:
                errors.append(source.report.line())
        return
    offsets = (0,) * part.first + part.offsets
    index = FrameIndex(offsets, frozenset(part.frame_channels), "")
    with fsspec.open(part.url, "rb") as f:
        t0 = time.perf_counter()
        for chunk in read_chunks(f, index, part.first, part.stop):
            read_ms = (time.perf_counter() - t0) * 1e3
            if chunk.error:
                stats["frames_in"] += 1
                stats["dropped"]["damaged"] += 1
                errors.append(chunk.error)
            for frame in chunk.frames:
                stats["frames_in"] += 1
                yield frame, read_ms
            t0 = time.perf_counter()


def _dataset_frames(part: Partition, stats: dict, errors: list[str]) -> Iterator[tuple[Frame, float]]:
    """The partition's frames of a dataset .npz; a read error (a damaged archive) drops the rest as damaged."""
    read = 0
    t0 = time.perf_counter()
    try:
        with DatasetFile(part.url) as dataset:
            for frame in dataset.read(part.first, part.stop):
                stats["frames_in"] += 1
                read += 1
                yield frame, (time.perf_counter() - t0) * 1e3
                t0 = time.perf_counter()
    except Exception as exc:  # noqa: BLE001 (zip, zlib or numpy errors of a damaged file: report, keep the rest)
        lost = part.frames - read
        stats["frames_in"] += lost
        stats["dropped"]["damaged"] += lost
        errors.append(f"frames {part.first + read}-{part.stop - 1}: {type(exc).__name__}: {exc}")


class FrameEvaluation:
    """The eval_* columns of frames with ground truth for one camera: per variant of the model, the frame's
    tofd.lab.evaluation.ImageMinima (true nose: within NOSE_RADIUS_M of the tip; the config's candidates).

    The samples are computed anew by the lab's frame_samples (all four families), not taken from process_frame's
    result: the pipeline computes the amplitude families only for an amplitude variant and does not keep the
    segmentation's face direction the candidates' front test needs, and `tofd evaluate` computes them so.
    """

    def __init__(self, cfg: Config, intrinsics: Intrinsics, model: NoseModel):
        self._extractor = FeatureExtractor(intrinsics, cfg.features, cfg.segmentation)
        self._model = model
        self._candidates = Candidates.from_config(cfg.detector, cfg.segmentation)

    def __call__(self, frame: Frame) -> dict:
        """The frame's eval_* columns; {} (null) without ground truth or its 3-D tip. A nose not visible counts
        as an image without a nose (its tip unknown), as in tofd.lab.evaluation.extract_samples."""
        truth = frame.ground_truth
        if truth is None or truth.nose_xyz_m is None:
            return {}
        tip = np.asarray(truth.nose_xyz_m, dtype=np.float64)
        samples = frame_samples(self._extractor, frame.range_m, frame.amplitude,
                                tip if truth.visible else np.full(3, np.nan))
        return eval_columns(image_minima(self._model, [samples], NOSE_RADIUS_M, self._candidates),
                            float(np.linalg.norm(tip)))


def run_partition(part_json: str, job_json: str) -> dict:
    """Process one partition (JSON of plan.Partition; job: runner.prepare's); returns
    its statistics (frames in/out, drops by reason, errors, time spent setting up, reading, computing, writing,
    in all, and the task's CPU time)."""
    prepare_process()
    t_start, cpu_start = time.perf_counter(), time.thread_time()
    part = Partition.from_json(part_json)
    job = json.loads(job_json)
    cfg = config_from_dict(job["config"])
    model = None if job["model"] is None else NoseModel.from_dict(job["model"])
    stats: dict = {"output": part.output, "frames_in": 0, "frames_out": 0, "dropped": Counter(), "errors": [],
                   "setup_ms": 0.0, "read_ms": 0.0, "compute_ms": 0.0, "write_ms": 0.0, "pid": os.getpid()}
    rows: list[dict] = []
    stage_intrinsics: Intrinsics | None = None
    for frame, read_ms in _frames(part, stats, stats["errors"]):
        stats["read_ms"] += read_ms
        t0 = time.perf_counter()
        if frame.intrinsics != stage_intrinsics:
            stage_intrinsics = frame.intrinsics  # each frame carries its camera's intrinsics (as replay uses)
            stage = FeatureStage(replace(cfg, intrinsics=stage_intrinsics), stage_intrinsics, model)
            slot = local_slot(stage_intrinsics.shape)
            evaluation = FrameEvaluation(cfg, stage_intrinsics, model) if model and job["evaluation"] else None
            stats["setup_ms"] += (time.perf_counter() - t0) * 1e3
            t0 = time.perf_counter()
        try:
            result = process_frame(stage, frame, slot)
            t_eval = time.perf_counter()
            evaluated = {} if evaluation is None else evaluation(frame)
        except Exception as exc:  # noqa: BLE001 (a bad frame is dropped with its reason, the others go on)
            stats["dropped"]["features"] += 1
            stats["errors"].append(f"frame {frame.frame_counter}: {type(exc).__name__}: {exc}")
            continue
        result.timings_ms["read"] = read_ms
        if evaluated:
            result.timings_ms["evaluation"] = (time.perf_counter() - t_eval) * 1e3
        rows.append({**frame_row(result), **evaluated})
        stats["compute_ms"] += (time.perf_counter() - t0) * 1e3
    stats["frames_out"] = len(rows)
    stats["dropped"] = dict(stats["dropped"])
    stats["errors"] = stats["errors"][:20]
    t0 = time.perf_counter()
    table = pa.Table.from_pylist(rows, schema=ROW_SCHEMA)
    stats["write_ms"] = 0.0
    stats["task_ms"] = (t0 - t_start) * 1e3
    fs, path = fsspec.core.url_to_fs(part.output)
    fs.makedirs(fs._parent(path), exist_ok=True)
    parent, name = path.rsplit("/", 1)
    tmp = f"{parent}/.{name}.tmp-{os.getpid()}"  # a leading ".": dataset readers skip it until it is renamed
    meta = {STATS_KEY: json.dumps(stats).encode()}
    with fs.open(tmp, "wb") as fh:
        pq.write_table(table.replace_schema_metadata(meta), fh)
    fs.mv(tmp, path)
    stats["write_ms"] = (time.perf_counter() - t0) * 1e3
    stats["task_ms"] = (time.perf_counter() - t_start) * 1e3
    stats["cpu_ms"] = (time.thread_time() - cpu_start) * 1e3
    return stats


def partition_stats(output: str) -> dict | None:
    """The statistics stored in a finished partition file, or None if there is no such (complete) file."""
    fs, path = fsspec.core.url_to_fs(output)
    try:
        if not fs.exists(path):
            return None
        with fs.open(path, "rb") as fh:
            meta = pq.read_schema(fh).metadata or {}
        return json.loads(meta[STATS_KEY])
    except Exception:  # noqa: BLE001 (an unreadable file is not done: it is processed again)
        return None
