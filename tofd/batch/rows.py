"""One per-frame result row (the replay results record, map digests and means, stage timings) and its Parquet
schema: what `tofd batch` writes and the golden check compares."""

from __future__ import annotations

import hashlib

import numpy as np
import pyarrow as pa

from tofd.algorithm.names import MAP_NAMES
from tofd.service.pipeline.results import FrameResult, finite_or_none, result_record

TIMED = ("read", "segmentation", "fft", "nfft", "detection")
"""Stages timed per frame in batch rows (ms): reading from storage, then the worker's stages."""

_FLOAT_LIST = pa.list_(pa.float64())
ROW_SCHEMA = pa.schema(
    [("frame_counter", pa.int64()), ("timestamp_us", pa.int64()), ("host_wall_s", pa.float64()),
     ("foreground_px", pa.int64()), ("nose_px", _FLOAT_LIST), ("nose_xyz_m", _FLOAT_LIST), ("score", pa.float64()),
     ("accepted", pa.bool_()), ("ground_truth_px", _FLOAT_LIST), ("ground_truth_xyz_m", _FLOAT_LIST),
     ("ground_truth_visible", pa.bool_()), ("nfft_iterations", pa.int64()),
     ("nfft_residual", pa.float64()), ("mask_digest", pa.string())]
    + [(f"digest_{name}", pa.string()) for name in MAP_NAMES]
    + [(f"mean_{name}", pa.float64()) for name in MAP_NAMES]
    + [(f"t_{stage}_ms", pa.float64()) for stage in TIMED]
)
"""Columns of a batch results file; digest_* / mean_* are null for maps not computed (all NaN)."""

TIMING_COLUMNS = tuple(f"t_{stage}_ms" for stage in TIMED)


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
        m = r.features[name]
        finite = np.isfinite(m)
        computed = bool(finite.any())
        row[f"digest_{name}"] = array_digest(m) if computed else None
        row[f"mean_{name}"] = float(np.mean(m[finite], dtype=np.float64)) if computed else None
    for stage in TIMED:
        row[f"t_{stage}_ms"] = timings.get(stage)
    return row


def without_timings(row: dict) -> dict:
    """A row without its t_*_ms columns: what must not change between runs."""
    return {k: v for k, v in row.items() if k not in TIMING_COLUMNS}


def rows_digest(rows: list[dict]) -> str:
    """sha256 of rows (without timings) in order, typed by ROW_SCHEMA (rows read back from Parquet give the same):
    equal digests mean bit-identical per-frame results."""
    h = hashlib.sha256()
    for row in pa.Table.from_pylist(rows, schema=ROW_SCHEMA).to_pylist():
        h.update(repr(sorted(without_timings(row).items())).encode())
    return h.hexdigest()
