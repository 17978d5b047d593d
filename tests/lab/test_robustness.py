"""Robustness matrix and head-motion sequences: real rendering, real features, the shipped model."""

from __future__ import annotations

import numpy as np
import pytest

from tofd.algorithm.detector import Candidates
from tofd.algorithm.tracking import TrackerConfig
from tofd.config import load_config
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab.conditions import CONDITIONS, TRAIN_CONDITION, parse_conditions
from tofd.lab.robustness import MatrixSpec, condition_table, run_matrix, summarize
from tofd.lab.sequences import evaluate_sequence, head_motion
from tofd.service.model import load_detector


def test_parse_conditions_names_unknown_ones():
    assert parse_conditions("all") == tuple(CONDITIONS)
    assert parse_conditions("no_wall, noise_x2") == ("no_wall", "noise_x2")
    with pytest.raises(ValueError, match="wall_9m"):
        parse_conditions("no_wall,wall_9m")


def test_matrix_cells_and_worst_cell():
    cfg = load_config(None)
    detector = load_detector(cfg)
    spec = MatrixSpec(conditions=(TRAIN_CONDITION, "no_wall"), subjects=("mp_bignose",), distances_m=(0.4, 0.6),
                      frames=3, seed=5)
    cells = run_matrix(detector.model, spec, cfg.features, cfg.segmentation,
                       Candidates.from_config(cfg.detector, cfg.segmentation), workers=1)
    assert len(cells) == 2 * 2 * 2  # conditions x distances x variants
    assert {(c.condition, c.distance_m) for c in cells} == {(n, d) for n in spec.conditions for d in (0.4, 0.6)}
    assert all(c.frames == 3 and 0 <= c.found + c.wrong <= 1 and 0 <= c.eer <= 1 for c in cells)
    assert all(c.found + c.rejected + c.outranked + c.no_candidate == pytest.approx(1.0) for c in cells)
    summary = summarize(cells)
    nfft = [c for c in cells if c.variant == "nfft_range"]
    assert summary["nfft_range"]["worst_eer"]["eer"] == max(c.eer for c in nfft)
    assert summary["nfft_range"]["worst_found"]["found"] == min(c.found for c in nfft)
    assert summary["nfft_range"]["mean"]["found"] == pytest.approx(np.mean([c.found for c in nfft]))
    assert summary["nfft_range"]["mean"]["rejected"] == pytest.approx(np.mean([c.rejected for c in nfft]))
    assert "no_wall" in condition_table(cells, "nfft_range")


def test_head_motion_sweeps_the_distances():
    poses = head_motion(np.array([0.0, 3.0, 6.0]), 6.0, Intrinsics())
    assert [p.distance_m for p in poses] == pytest.approx([0.35, 0.70, 0.35])
    assert [p.yaw_deg for p in poses[:2]] == pytest.approx([0.0, -30.0])


def test_sequence_track_is_reported_from_the_first_detection():
    cfg = load_config(None)
    detector = load_detector(cfg)
    r = evaluate_sequence(detector, "mp_bignose", 8, sweep_s=60.0, seed=1)
    assert r.detection_found >= 0.75  # near 0.35 m, training sensor: the detector finds the nose
    assert r.track_found >= r.detection_found and r.track_wrong == 0  # a new track is reported while associated
    late = evaluate_sequence(detector, "mp_bignose", 8, sweep_s=60.0, seed=1,
                             tracker=TrackerConfig(report_new=False))
    assert late.track_found + late.track_wrong <= 6 / 8  # without report_new the first two frames are tentative
    with pytest.raises(ValueError, match="nobody"):
        evaluate_sequence(detector, "nobody", 2)
