"""Scoring reported noses against ground truth (tofd.lab.accuracy): found, wrong, and the track's."""

from __future__ import annotations

import numpy as np

from tofd.lab.accuracy import accuracy_from_records


def record(counter: int, nose: list[float] | None, truth: list[float], track: list[float] | None) -> dict:
    """A results record as the pipeline writes it; track None: a confirmed track that reports no pixel (coasting)."""
    return {"frame_counter": counter, "nose_px": nose, "ground_truth_px": truth, "score": 0.1,
            "track": {"status": "tracking" if track else "coasting", "nose_px": track}}


def test_found_wrong_and_missing_frames_are_counted_apart():
    truth = [80.0, 60.0]
    records = [
        record(0, [81.0, 61.0], truth, [80.0, 60.0]),  # found (1.4 px), track found
        record(1, [90.0, 60.0], truth, [80.0, 64.0]),  # wrong (10 px), track found (4 px)
        record(2, None, truth, [95.0, 60.0]),  # nothing reported, track wrong (15 px)
        record(3, [84.9, 60.0], truth, None),  # found at 4.9 px, no confirmed track
        {"frame_counter": 4, "nose_px": [0.0, 0.0], "ground_truth_px": None},  # no truth: not scored
    ]
    acc = accuracy_from_records(records, radius_px=5.0)
    assert acc is not None and len(acc.error_px) == 4
    assert (acc.found, acc.wrong) == (2, 1)
    assert (acc.track_found, acc.track_wrong) == (2, 1)
    assert np.isnan(acc.error_px[2]) and np.isnan(acc.track_error_px[3])


def test_results_without_a_track_have_no_track_counts():
    acc = accuracy_from_records([{"frame_counter": 0, "nose_px": [1.0, 1.0], "ground_truth_px": [1.0, 1.0]}])
    assert acc is not None and acc.found == 1 and acc.wrong == 0
    assert acc.track_found is None and acc.track_wrong is None


def test_the_refined_tip_is_scored_where_the_record_has_one():
    truth = [80.0, 60.0]
    records = [{**record(0, [86.0, 60.0], truth, None), "tip_px": [80.5, 60.2]},  # pixel 6 px off, its tip 0.5 px
               {**record(1, [81.0, 60.0], truth, None), "tip_px": None}]  # no tip: the pixel itself
    acc = accuracy_from_records(records, radius_px=5.0)
    assert acc is not None and acc.found == 2 and acc.wrong == 0
    np.testing.assert_allclose(acc.error_px, [np.hypot(0.5, 0.2), 1.0])
