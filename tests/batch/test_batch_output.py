"""`tofd batch` as a real command: its output directory opens as a Hive-partitioned dataset in pyarrow and DuckDB
without options, stderr carries tofd's lines only, --resume and a glob matching nothing report cleanly."""

import json
import subprocess
import sys
from pathlib import Path

import duckdb
import pyarrow.dataset as ds
import pytest

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def batch(*args):
    return subprocess.run([sys.executable, "-m", "tofd", "batch", *map(str, args), "--workers", "1"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_batch_output_is_a_hive_dataset_and_its_stderr_is_tofds(tmp_path):
    out = tmp_path / "out"
    run = batch(CLIP, "--out", out, "--no-evaluation", "--partition-frames", "40")
    assert run.returncode == 0, run.stderr
    lines = run.stderr.splitlines()
    assert all(line.startswith(("tofd ", "tofd: ")) or line.startswith(" ") or line[:1].isdigit() for line in lines
               if "%" not in line), lines  # progress bars aside: no Dask INFO lines, no Python warnings
    assert not [line for line in lines if "INFO" in line or "Warning" in line]
    summary = json.loads((out / "_summary.json").read_text())
    assert summary["frames_out"] == 101
    table = ds.dataset(out, partitioning="hive").to_table()
    assert table.num_rows == 101 and set(table.column("recording").to_pylist()) == {"emulated_face_035_070"}
    assert sorted(table.column("frame_counter").to_pylist()) == list(range(101))
    rows = duckdb.sql(f"SELECT recording, count(*) FROM read_parquet('{out}/**/*.parquet', hive_partitioning=true) "
                      "GROUP BY recording").fetchall()
    assert rows == [("emulated_face_035_070", 101)]

    again = batch(CLIP, "--out", out, "--no-evaluation", "--partition-frames", "40", "--resume")
    assert again.returncode == 0, again.stderr
    last = again.stderr.strip().splitlines()[-1]
    assert "3 resumed" in last and "nothing computed" in last and "None" not in last


def test_a_glob_matching_nothing_is_a_data_error(tmp_path):
    run = batch(tmp_path / "*.mcap", "--out", tmp_path / "out")
    assert run.returncode == 2, run.stderr
    assert "matches no recording or dataset" in run.stderr and "Traceback" not in run.stderr
