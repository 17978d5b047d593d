"""Golden replay check: the bundled clip replays to its golden file (the CI check), and the check fails with a
readable diff when results move."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tofd.batch.golden import TOLERANCES, compare, load_golden, tolerance

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"
GOLDEN = ROOT / "replay_data" / "emulated_face_035_070.golden.json"


def replay(out: Path, *args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tofd", "replay", str(CLIP), "--out", str(out), "--rerun", "none",
                           *map(str, args)], cwd=ROOT, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def checked_replay(tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    """`tofd replay CLIP --check GOLDEN`, also writing what it saw as a golden file."""
    out = tmp_path_factory.mktemp("golden")
    proc = replay(out, "--check", GOLDEN, "--write-golden", out / "run.golden.json")
    return proc, out


def test_bundled_clip_matches_its_golden_file(checked_replay):
    """The replay agrees with the golden file within the stated tolerances (bit identity is reported, never
    required: the file was written on another CPU), and the check says what it compared."""
    proc, out = checked_replay
    assert proc.returncode == 0, proc.stderr
    assert "check passed" in proc.stderr
    assert "compared 101 frames: frame counters and timestamp_us, foreground_px, nose_px, accepted" in proc.stderr
    run = load_golden(out / "run.golden.json")
    golden = load_golden(GOLDEN)
    assert len(run["frames"]) == len(golden["frames"]) == 101
    report = compare(golden, run["frames"])
    assert report.problems == () and report.frames_compared == 101
    identical = run["results_digest"] == golden["results_digest"]
    assert report.bit_identical == identical
    assert ("bit-identical to the golden file" in proc.stderr) == identical
    assert ("not bit-identical" in proc.stderr) == (not identical)
    # the golden rows are the replay's results.jsonl records (plus digests): same detections, frame by frame
    records = [json.loads(line) for line in (out / "emulated_face_035_070.results.jsonl").read_text().splitlines()]
    for rec, row in zip(records, golden["frames"], strict=True):
        for key in ("frame_counter", "nose_px", "accepted", "foreground_px"):
            assert rec[key] == row[key], (rec["frame_counter"], key)
        assert TOLERANCES["score"].accepts(rec["score"], row["score"]), rec["frame_counter"]
        assert abs(rec["nfft_iterations"] - row["nfft_iterations"]) <= TOLERANCES["nfft_iterations"].abs
    assert any(r["accepted"] for r in golden["frames"])  # the clip has detections to protect


def _map_mean_fields(frame: dict, family: str) -> list[str]:
    return [k for k, v in frame.items() if k.startswith("mean_") and f"_{family}_" in k and v is not None]


@pytest.mark.parametrize("field", ["score", "nose_xyz_m", "nfft_iterations", "nfft_residual", "nfft mean",
                                   "fft mean"])
def test_each_tolerance_passes_inside_and_fails_outside(field):
    """A golden value moved by half its tolerance (a count: by its tolerance) passes, not bit-identical and said
    so; moved by three times its tolerance it fails, naming the frame, the field and the tolerance."""
    golden = load_golden(GOLDEN)
    frame = next(r for r in golden["frames"] if r["accepted"] and r["nfft_residual"] is not None)
    name = _map_mean_fields(frame, field.split()[0])[0] if field.endswith("mean") else field
    tol = tolerance(name)
    assert tol is not None

    def moved(factor: float) -> list[dict]:
        rows = copy.deepcopy(golden["frames"])
        row = next(r for r in rows if r["frame_counter"] == frame["frame_counter"])
        value = row[name]
        first = value[0] if isinstance(value, list) else value
        step = factor * max(tol.rel * abs(first), tol.abs)
        row[name] = [first + step, *value[1:]] if isinstance(value, list) else first + step
        return rows

    inside = compare(golden, moved(1.0 if isinstance(frame[name], int) else 0.5))  # a count moves by whole steps
    assert inside.problems == () and not inside.bit_identical
    assert any("not bit-identical" in n for n in inside.notes)
    assert any(f"{name} " in n for n in inside.notes if n.startswith("largest differences"))
    rows = moved(3.0)
    outside = compare(golden, rows)
    assert outside.problems == (f"frame {frame['frame_counter']}: {name} {frame[name]!r} -> "
                                f"{rows[golden['frames'].index(frame)][name]!r} (tolerance {tol})",)


def test_check_reports_moved_detections_and_is_exact_on_pixels_and_frames():
    golden = load_golden(GOLDEN)
    same = compare(golden, copy.deepcopy(golden["frames"]))
    assert same.problems == () and same.bit_identical and same.frames_compared == 101
    assert any(n.startswith("bit-identical to the golden file") for n in same.notes)
    rows = copy.deepcopy(golden["frames"])
    accepted = next(r for r in rows if r["accepted"])
    accepted["nose_px"] = [accepted["nose_px"][0] + 1, accepted["nose_px"][1]]
    rows[5]["foreground_px"] += 1
    rows[6]["score"] += 1e-9 * rows[6]["score"]  # within tolerance: not a regression
    del rows[-1]
    report = compare(golden, rows)
    text = "\n".join(report.problems)
    assert f"frame {accepted['frame_counter']}: nose_px" in text and "(exact)" in text
    assert f"frame {rows[5]['frame_counter']}: foreground_px" in text
    assert f"frame {rows[6]['frame_counter']}:" not in text
    assert "frames missing from the run: 1" in text
    assert report.frames_compared == 100 and not report.bit_identical


@pytest.mark.slow
def test_check_exits_1_with_a_readable_diff(tmp_path):
    proc = replay(tmp_path, "--frames", "4", "--check", GOLDEN)
    assert proc.returncode == 1
    assert "check FAILED" in proc.stderr
    assert "frames missing from the run: 97" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_check_rejects_a_file_that_is_not_golden(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"frames": []}')
    with pytest.raises(ValueError, match="not a golden file"):
        load_golden(bad)


def test_the_check_holds_when_cg_stops_at_other_iterations(tmp_path):
    """Another CPU's rounding may stop the single-precision CG some iterations earlier or later: the same clip with
    the CG threshold lowered (a model copy and config that say so) stops elsewhere on many frames and still passes
    the check against the golden file, with every detection the same."""
    model = json.loads((ROOT / "config" / "nose_model.json").read_text())
    model["feature_config"]["cg_tolerance"] = 5e-5
    (tmp_path / "nose_model.json").write_text(json.dumps(model))
    text = (ROOT / "config" / "tofd.toml").read_text()
    assert "\ncg_tolerance = 7e-5" in text
    (tmp_path / "tofd.toml").write_text(text.replace("\ncg_tolerance = 7e-5", "\ncg_tolerance = 5e-5"))
    out = tmp_path / "out"
    proc = replay(out, "--config", tmp_path / "tofd.toml", "--check", GOLDEN)
    assert proc.returncode == 0, proc.stderr
    assert "check passed" in proc.stderr and "not bit-identical" in proc.stderr
    records = [json.loads(line) for line in (out / "emulated_face_035_070.results.jsonl").read_text().splitlines()]
    golden = load_golden(GOLDEN)["frames"]
    moved = [r for r, g in zip(records, golden, strict=True) if r["nfft_iterations"] != g["nfft_iterations"]]
    assert len(moved) >= 10  # the perturbation is real: CG stopped at another iteration on these frames
    assert max(abs(r["score"] / g["score"] - 1) for r, g in zip(records, golden, strict=True) if g["score"]) > 1e-3
