import json

import numpy as np
import pytest

from tofd.cli import main
from tofd.config import FeatureConfig
from tofd.drivers.intrinsics import Intrinsics
from tofd.lab import sphere_experiment as experiment_sphere

CFG = FeatureConfig()


@pytest.fixture(scope="module")
def points():
    return experiment_sphere.run(Intrinsics(), CFG)


def test_nfft_eps0_scale_invariant_within_2_percent(points):
    at_e = next(p for p in points if p.distance_m == CFG.equivalence_range_m)
    assert points[0].distance_m == 0.3 and points[-1].distance_m == 0.9
    for p in points:
        assert p.nfft_eps0 == pytest.approx(at_e.nfft_eps0, rel=0.02)


def test_eps2_vanishes_at_apex(points):
    for p in points:
        assert p.nfft_eps2 <= 1e-6 * p.nfft_eps0
        assert p.fft_eps2 <= 1e-6 * p.fft_eps0


def test_fft_monotone_and_agrees_with_nfft_at_e(points):
    fft = np.array([p.fft_eps0 for p in points])
    assert np.all(np.diff(fft) > 0)
    at_e = next(p for p in points if p.distance_m == CFG.equivalence_range_m)
    assert at_e.fft_eps0 == pytest.approx(at_e.nfft_eps0, rel=0.05)


def test_command_writes_table_png_and_json(tmp_path, capsys):
    assert main(["experiment", "sphere", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "NFFT eps0" in out and "0.90" in out
    data = json.loads((tmp_path / "sphere.json").read_text())
    assert len(data["points"]) == 13 and data["summary"]["fft_monotone"] is True
    png = (tmp_path / "sphere.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
