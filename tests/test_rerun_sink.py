"""Rerun sink: every delivered frame's entities arrive in the .rrd (read back with Rerun's own reader)."""

import json

import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from pipeline_sources import RenderedSource
from rerun.chunk import RrdReader

from tofd.config import Config
from tofd.pipeline import Pipeline
from tofd.viewer import RerunLogger, RerunTarget
from tofd.viewer import blueprint as bp

PER_FRAME = [bp.RANGE, bp.AMPLITUDE, bp.MASK, bp.FOREGROUND, *bp.FEATURES.values(), f"{bp.TIMINGS}/nfft",
             f"{bp.TIMINGS}/logging", f"{bp.TIMINGS}/latency"]


def read_entities(path):
    """entity path -> (static chunks, pyarrow table of the temporal rows sorted by frame)."""
    chunks = list(RrdReader(path).stream().to_chunks())
    tables = {}
    for entity in {c.entity_path for c in chunks}:
        batches = [c.to_record_batch() for c in chunks if c.entity_path == entity and not c.is_static]
        static = [c for c in chunks if c.entity_path == entity and c.is_static]
        table = pa.Table.from_batches(batches).sort_by("frame") if batches else None
        tables[entity] = (static, table)
    return tables


def image_at(table, archetype, row):
    fmt = table.column(f"{archetype}:format")[row].as_py()[0]
    blob = table.column(f"{archetype}:buffer")[row].values[0].values
    dtype = rr.ChannelDatatype(fmt["channel_datatype"]).to_np_dtype()
    return np.frombuffer(blob.to_numpy(zero_copy_only=False).tobytes(), dtype=dtype).reshape(fmt["height"],
                                                                                              fmt["width"])


def check_rrd(path, counters, results_by_counter=None):
    """Every entity logged per frame has one row for each delivered frame counter (None: the same rows as the
    range image); statics are there."""
    tables = read_entities(str(path))
    if counters is None:
        counters = tables[bp.RANGE][1].column("frame").to_pylist()
    for entity in PER_FRAME:
        assert entity in tables, f"{entity} missing from {path}"
        rows = tables[entity][1].column("frame").to_pylist()
        assert rows == counters, entity
    assert tables[bp.CAMERA][0], "the Pinhole is logged statically"
    device_time = tables[bp.RANGE][1].column("device_time").cast(pa.int64()).to_numpy()
    assert np.all(np.diff(device_time) > 0)
    if results_by_counter:
        c = counters[-1]
        range_m = image_at(tables[bp.RANGE][1], "DepthImage", len(counters) - 1)
        expected = np.nan_to_num(results_by_counter[c].frame.range_m, nan=0.0)
        np.testing.assert_array_equal(range_m, expected)
        cloud = tables[bp.FOREGROUND][1].column("Points3D:positions")[len(counters) - 1]
        assert len(cloud) == int(results_by_counter[c].mask.sum())
    return tables


def test_saved_rrd_holds_every_frame(tmp_path):
    cfg = Config()
    path = tmp_path / "run.rrd"
    target = RerunTarget(cfg.rerun, "save", path=str(path))
    kept = {}
    pipeline = Pipeline(cfg, "lossless", viewer=RerunLogger(target.rec, cfg.intrinsics),
                        writers=(lambda r: kept.__setitem__(r.frame.frame_counter, r),))
    source = RenderedSource(20, skip_counters=(7,), n_distinct=3)
    pipeline.start(source)
    assert pipeline.wait(60)
    summary = pipeline.close()
    target.close()
    assert summary["frames_out"] == 19 and summary["consistent"]
    tables = check_rrd(path, source.emitted, kept)
    events = tables[bp.EVENTS][1]
    assert events.column("frame").to_pylist() == [8]
    assert "counter_gap" in events.column("TextLog:text")[0].as_py()[0]
    assert RrdReader(str(path)).blueprints(), "the blueprint is stored with the recording"


def test_bad_sink_is_rejected():
    with pytest.raises(ValueError, match="sink"):
        RerunTarget(Config().rerun, "telepathy")


def test_results_lines_match_delivered_frames(tmp_path):
    from tofd.pipeline import ResultsWriter

    writer = ResultsWriter(tmp_path / "r.jsonl")
    pipeline = Pipeline(Config(), "lossless", writers=(writer,))
    pipeline.start(RenderedSource(6, n_distinct=2))
    assert pipeline.wait(60)
    pipeline.close()
    writer.close()
    lines = [json.loads(x) for x in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert [x["frame_counter"] for x in lines] == list(range(6))
    assert all(x["timings_ms"]["nfft"] > 0 and x["ground_truth_px"] is not None for x in lines)
