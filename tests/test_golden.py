"""Golden replay check: the bundled clip replays to its golden file (the CI check), and the check fails with a
readable diff when results move."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tofd.batch.golden import compare, load_golden

ROOT = Path(__file__).resolve().parent.parent
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
    proc, out = checked_replay
    assert proc.returncode == 0, proc.stderr
    assert "check passed" in proc.stderr
    run = load_golden(out / "run.golden.json")
    golden = load_golden(GOLDEN)
    assert len(run["frames"]) == 101
    assert run["results_digest"] == golden["results_digest"]  # bit-identical per-frame results, maps included
    # the golden rows are the replay's results.jsonl records (plus digests): same detections, frame by frame
    records = [json.loads(line) for line in (out / "emulated_face_035_070.results.jsonl").read_text().splitlines()]
    for rec, row in zip(records, golden["frames"], strict=True):
        for key in ("frame_counter", "nose_px", "score", "accepted", "nfft_iterations", "foreground_px"):
            assert rec[key] == row[key], (rec["frame_counter"], key)
    assert any(r["accepted"] for r in golden["frames"])  # the clip has detections to protect


def test_check_reports_moved_detections_and_tolerates_small_noise():
    golden = load_golden(GOLDEN)
    rows = copy.deepcopy(golden["frames"])
    assert compare(golden, rows)[0] == []
    accepted = next(r for r in rows if r["accepted"])
    accepted["nose_px"] = [accepted["nose_px"][0] + 3, accepted["nose_px"][1]]
    rows[5]["score"] += 0.01
    rows[6]["score"] += 1e-9  # within tolerance: not a regression
    rows[7]["mean_range_fft_eps0"] += 1e-7
    del rows[-1]
    problems, _ = compare(golden, rows)
    text = "\n".join(problems)
    assert f"frame {accepted['frame_counter']}: nose_px" in text
    assert f"frame {rows[5]['frame_counter']}: score" in text
    assert f"frame {rows[6]['frame_counter']}:" not in text
    assert f"frame {rows[7]['frame_counter']}:" not in text
    assert "frames missing from the run: 1" in text


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
