"""Rerun sink: every delivered frame's entities arrive in the .rrd (read back with Rerun's own reader)."""

import json

import pytest
from pipeline_sources import RenderedSource
from rerun.chunk import RrdReader
from rrd_helpers import check_rrd

from tofd.config import Config
from tofd.service.pipeline import Pipeline
from tofd.service.viewer import RerunLogger, RerunTarget
from tofd.service.viewer import blueprint as bp


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
    from tofd.service.pipeline import ResultsWriter

    writer = ResultsWriter(tmp_path / "r.jsonl")
    pipeline = Pipeline(Config(), "lossless", writers=(writer,))
    pipeline.start(RenderedSource(6, n_distinct=2))
    assert pipeline.wait(60)
    pipeline.close()
    writer.close()
    lines = [json.loads(x) for x in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert [x["frame_counter"] for x in lines] == list(range(6))
    assert all(x["timings_ms"]["nfft"] > 0 and x["ground_truth_px"] is not None for x in lines)
