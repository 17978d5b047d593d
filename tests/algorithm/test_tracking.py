"""The nose track: gating, coasting through misses, rejecting outliers, loss and re-acquisition."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from tofd.algorithm.tracking import NoseTracker, TrackerConfig

DT = 1 / 25


@dataclass(frozen=True)
class Det:
    answer_xyz_m: tuple[float, float, float] | None
    accepted: bool = True
    alternatives: tuple = ()


@dataclass(frozen=True)
class Alt:
    answer_xyz_m: tuple[float, float, float]
    score: float


def rejected(*alternatives: tuple[float, float]) -> Det:
    """A frame whose own answer was rejected, with alternatives at (x, score) each (y = 0, z = 0.5)."""
    return Det(None, False, tuple(Alt((x, 0.0, 0.5), score) for x, score in alternatives))


def det(x: float, y: float = 0.0, z: float = 0.5) -> Det:
    return Det((x, y, z))


MISS = Det(None, False)


def run(tracker: NoseTracker, detections: list[Det], t0: float = 0.0) -> list:
    return [tracker.update(d, t0 + i * DT) for i, d in enumerate(detections)]


def test_confirmed_after_confirm_hits_and_follows_constant_velocity() -> None:
    tracker = NoseTracker()
    speed = 0.2  # m/s along x
    states = run(tracker, [det(speed * i * DT) for i in range(40)])
    assert [s.status for s in states[:3]] == ["tentative", "tentative", "tracking"]
    assert all(s.associated for s in states)
    assert states[-1].velocity_m_per_s[0] == pytest.approx(speed, abs=0.01)
    assert states[-1].nose_xyz_m[0] == pytest.approx(speed * 39 * DT, abs=1e-3)
    assert states[-1].confidence > 0.99


def test_coasts_through_misses_on_the_predicted_path() -> None:
    tracker = NoseTracker()
    speed = 0.2
    run(tracker, [det(speed * i * DT) for i in range(30)])
    coasting = [tracker.update(MISS, (30 + k) * DT) for k in range(5)]
    assert all(s.confirmed and not s.associated for s in coasting)  # reported only for report_coast_s
    assert coasting[-1].nose_xyz_m[0] == pytest.approx(speed * 34 * DT, abs=2e-3)
    assert coasting[-1].confidence < coasting[0].confidence < 1.0


def test_a_single_outlier_is_gated_out() -> None:
    tracker = NoseTracker()
    run(tracker, [det(0.0)] * 10)
    state = tracker.update(det(0.08), 10 * DT)  # a wrong pixel 8 cm away
    assert state.reported and not state.associated and not state.reacquired
    assert state.nose_xyz_m[0] == pytest.approx(0.0, abs=1e-6)
    state = tracker.update(det(0.001), 11 * DT)
    assert state.associated


def test_persistent_jump_is_reacquired_after_confirm_hits() -> None:
    cfg = TrackerConfig()
    tracker = NoseTracker(cfg)
    run(tracker, [det(0.0)] * 10)
    states = [tracker.update(det(0.10), (10 + k) * DT) for k in range(cfg.confirm_hits)]
    assert [s.reacquired for s in states] == [False] * (cfg.confirm_hits - 1) + [True]
    assert states[-1].nose_xyz_m[0] == pytest.approx(0.10, abs=1e-6)
    assert tracker.update(det(0.10), (10 + cfg.confirm_hits) * DT).associated


def test_lost_after_lost_after_s_then_restarts() -> None:
    cfg = TrackerConfig(lost_after_s=0.2)
    tracker = NoseTracker(cfg)
    run(tracker, [det(0.0)] * 5)
    states = [tracker.update(MISS, (5 + k) * DT) for k in range(10)]
    lost = [s.status for s in states]
    assert lost[0] == "tracking" and lost[-1] == "none"
    assert states[-1].nose_xyz_m is None and states[-1].confidence == 0.0
    restart = tracker.update(det(0.3), 15 * DT)
    assert restart.status == "tentative" and restart.reacquired


def test_a_confirmed_track_coasts_unreported_after_report_coast_s_and_resumes_on_a_hit() -> None:
    cfg = TrackerConfig(report_coast_s=1.5 * DT, lost_after_s=10 * DT)
    tracker = NoseTracker(cfg)
    run(tracker, [det(0.0)] * 5)
    states = [tracker.update(MISS, (5 + k) * DT) for k in range(4)]
    assert [s.status for s in states] == ["tracking", "coasting", "coasting", "coasting"]
    assert [s.reported for s in states] == [True, False, False, False]
    assert all(s.confirmed and s.nose_xyz_m is not None for s in states)  # still predicted, for the gate
    back = tracker.update(det(0.0), 9 * DT)
    assert back.associated and back.status == "tracking" and not back.reacquired  # the same track, no re-acquisition


def test_gate_grows_with_time_since_last_hit() -> None:
    cfg = TrackerConfig(gate_m=0.02, gate_growth_m_per_s=0.25, lost_after_s=1.0)
    near, far = NoseTracker(cfg), NoseTracker(cfg)
    for tracker in (near, far):
        run(tracker, [det(0.0)] * 5)
    # 3.5 cm away: outside the 2 + 1 cm gate one frame later, inside the 2 + 6 cm gate after 0.24 s
    assert not near.update(det(0.035), 5 * DT).associated
    for k in range(5):
        far.update(MISS, (5 + k) * DT)
    assert far.update(det(0.035), 10 * DT).associated


def test_velocity_is_clipped() -> None:
    cfg = TrackerConfig(gate_m=1.0, max_speed_m_per_s=0.5)
    tracker = NoseTracker(cfg)
    states = run(tracker, [det(2.0 * i * DT) for i in range(20)])
    assert np.linalg.norm(states[-1].velocity_m_per_s) <= 0.5 + 1e-9


@pytest.mark.parametrize("key, value", [("gate_m", 0.0), ("alpha", 1.5), ("confirm_hits", 0),
                                        ("gate_growth_m_per_s", -1.0)])
def test_bad_config_names_the_key(key: str, value: float) -> None:
    with pytest.raises(ValueError, match=key):
        NoseTracker(TrackerConfig(**{key: value}))


def test_a_confirmed_track_takes_the_best_alternative_inside_its_gate() -> None:
    tracker = NoseTracker()
    run(tracker, [det(0.0)] * 5)
    gate = tracker.config.gate_m
    state = tracker.update(rejected((0.3, 0.5), (0.004, 1.2), (-0.006, 0.9)), 5 * DT)
    assert state.associated and state.assisted and state.reported
    assert state.nose_xyz_m[0] == pytest.approx(tracker.config.alpha * -0.006)  # the better of the two inside
    state = tracker.update(rejected((gate * 3, 0.1)), 6 * DT)  # only one far outside the gate: not associated
    assert not state.associated and not state.assisted


def test_alternatives_neither_start_nor_confirm_a_track() -> None:
    tracker = NoseTracker()
    states = run(tracker, [rejected((0.0, 0.5))] * 3 + [det(0.0), rejected((0.0, 0.5))])
    assert [s.status for s in states] == ["none"] * 3 + ["tentative", "tentative"]
    assert not any(s.assisted for s in states)
