"""One per-frame result row (the replay results record, map digests and means, stage timings, and the evaluation's
per-image minima where the frame has ground truth) and its Parquet schema: what `tofd batch` writes; the golden
check compares its pipeline fields."""

from __future__ import annotations

import hashlib

import numpy as np
import pyarrow as pa

from tofd.algorithm.names import MAP_NAMES, VARIANTS
from tofd.lab.evaluation import ImageMinima
from tofd.service.pipeline.results import FrameResult, finite_or_none, result_record

TIMED = ("read", "segmentation", "fft", "nfft", "detection", "evaluation")
"""Stages timed per frame in batch rows (ms): reading from storage, the worker's stages, then the evaluation of
a frame with ground truth (tofd.batch.task.FrameEvaluation)."""

_FLOAT_LIST = pa.list_(pa.float64())
ROW_SCHEMA = pa.schema(
    [("frame_counter", pa.int64()), ("timestamp_us", pa.int64()), ("host_wall_s", pa.float64()),
     ("foreground_px", pa.int64()), ("nose_px", _FLOAT_LIST), ("nose_xyz_m", _FLOAT_LIST),
     ("tip_px", _FLOAT_LIST), ("tip_xyz_m", _FLOAT_LIST), ("score", pa.float64()),
     ("accepted", pa.bool_()), ("ground_truth_px", _FLOAT_LIST), ("ground_truth_xyz_m", _FLOAT_LIST),
     ("ground_truth_visible", pa.bool_()), ("nfft_iterations", pa.int64()),
     ("nfft_residual", pa.float64()), ("mask_digest", pa.string())]
    + [(f"digest_{name}", pa.string()) for name in MAP_NAMES]
    + [(f"mean_{name}", pa.float64()) for name in MAP_NAMES]
    + [(f"t_{stage}_ms", pa.float64()) for stage in TIMED]
    + [("eval_has_nose", pa.bool_()), ("eval_distance_m", pa.float64())]
    + [(f"eval_{kind}_{variant}", pa.float64()) for variant in VARIANTS for kind in ("true_min", "false_min", "rival")]
)
"""Columns of a batch results file; digest_* / mean_* are null for maps not computed (all NaN); eval_* are null
for frames without ground truth (eval_columns)."""

TIMING_COLUMNS = tuple(f"t_{stage}_ms" for stage in TIMED)
EVAL_COLUMNS = tuple(name for name in ROW_SCHEMA.names if name.startswith("eval_"))


def array_digest(a: np.ndarray) -> str:
    """sha256 (first 16 hex digits) of an array's dtype, shape and little-endian bytes, every NaN made the same."""
    a = np.ascontiguousarray(a)
    if a.dtype.kind == "f":
        a = np.where(np.isnan(a), np.array(np.nan, a.dtype), a).astype(a.dtype.newbyteorder("<"))
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()[:16]


def frame_row(r: FrameResult) -> dict:
    """The row of one processed frame: result_record without its timings and track, plus host time, NFFT residual,
    the digests of the mask and each computed map, each map's mean over its finite values, and t_<stage>_ms.

    The track is left out because it depends on every earlier frame of the recording, while a batch partition
    sees only its own frames; it follows from the rows' detections and timestamps (tofd.algorithm.tracking)."""
    row = result_record(r)
    timings = row.pop("timings_ms")
    del row["track"]
    row["host_wall_s"] = r.frame.host_wall_s
    row["nfft_residual"] = finite_or_none(r.nfft_residual)
    row["mask_digest"] = array_digest(r.mask)
    for name in MAP_NAMES:
        m = r.features.get(name)  # absent: a family the run did not compute
        finite = np.isfinite(m) if m is not None else None
        if m is None or finite is None or not finite.any():
            row[f"digest_{name}"] = row[f"mean_{name}"] = None
        else:
            row[f"digest_{name}"] = array_digest(m)
            row[f"mean_{name}"] = float(np.mean(m[finite], dtype=np.float64))
    for stage in TIMED:
        row[f"t_{stage}_ms"] = timings.get(stage)
    return row


def eval_columns(minima: ImageMinima, distance_m: float) -> dict:
    """The eval_* columns of one frame from its ImageMinima (one image) and its nose distance (metres): what
    tofd.lab.evaluation.variant_results needs of it; variants the model lacks are null."""
    row: dict = {"eval_has_nose": bool(minima.has_nose[0]), "eval_distance_m": distance_m}
    for variant in VARIANTS:
        for kind, mins in (("true_min", minima.true_min), ("false_min", minima.false_min), ("rival", minima.rival)):
            row[f"eval_{kind}_{variant}"] = float(mins[variant][0]) if variant in mins else None
    return row


def minima_from_rows(rows: list[dict], variants: list[str]) -> tuple[ImageMinima, np.ndarray]:
    """The ImageMinima of the `variants` and the (F,) nose distances (metres) of the rows that carry eval_* columns,
    in order (the inverse of eval_columns)."""
    kept = [r for r in rows if r.get("eval_has_nose") is not None]

    def column(name: str) -> np.ndarray:
        return np.array([r[name] for r in kept], dtype=np.float64)

    return (ImageMinima(np.array([r["eval_has_nose"] for r in kept], dtype=bool),
                        {v: column(f"eval_true_min_{v}") for v in variants},
                        {v: column(f"eval_false_min_{v}") for v in variants},
                        {v: column(f"eval_rival_{v}") for v in variants}),
            column("eval_distance_m"))


def pipeline_fields(row: dict) -> dict:
    """A row without its t_*_ms columns (they vary between runs) and eval_* columns (batch only, from the ground
    truth): the pipeline's results, which a replay gives too and which must not change between runs."""
    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS and k not in EVAL_COLUMNS}


def rows_digest(rows: list[dict]) -> str:
    """sha256 of rows' pipeline_fields in order, typed by ROW_SCHEMA (rows read back from Parquet give the same):
    equal digests mean bit-identical per-frame results."""
    h = hashlib.sha256()
    for row in pa.Table.from_pylist(rows, schema=ROW_SCHEMA).to_pylist():
        h.update(repr(sorted(pipeline_fields(row).items())).encode())
    return h.hexdigest()
