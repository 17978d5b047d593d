"""`tofd batch` on a real Dask LocalCluster of 2 worker processes: the bundled clip in 5 partitions gives the
replay's results bit for bit (its golden file), also when a worker is killed mid-run; resume; bad inputs."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from drivers.recording.index import frame_index
from tofd.batch.golden import load_golden
from tofd.batch.rows import without_timings
from tofd.batch.runner import RunOptions, batch_client, prepare, read_rows, run_plan
from tofd.config import load_config

ROOT = Path(__file__).resolve().parent.parent
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"
GOLDEN = ROOT / "replay_data" / "emulated_face_035_070.golden.json"
PARTITION = 25  # 101 frames -> 5 partitions
QUIET = RunOptions(progress=False)


@pytest.fixture(scope="module")
def client():
    with batch_client(None, 2) as c:
        yield c


def run(client, out: Path, inputs: list[str], options: RunOptions = QUIET, on_done=None) -> dict:
    plans, job, digests = prepare(inputs, str(out), load_config(), PARTITION)
    return run_plan(client, plans, job, str(out), digests, options, on_done)


def outputs(summary: dict, out: Path, k: int = 0) -> list[str]:
    return [str(out / p) for p in summary["inputs"][k]["parts"]]


@pytest.fixture(scope="module")
def clip_run(client, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("batch")
    return run(client, out, [str(CLIP)]), out


def test_partitions_equal_the_replay(clip_run):
    summary, out = clip_run
    golden = load_golden(GOLDEN)  # what `tofd replay` gives (tests/test_golden.py checks it on a real replay)
    assert summary["partitions"] == {"total": 5, "computed": 5, "resumed": 0, "failed": 0}
    assert len(list((out / "recording=emulated_face_035_070").glob("part-*.parquet"))) == 5
    rows = read_rows(outputs(summary, out))
    assert [without_timings(r) for r in rows] == golden["frames"]
    assert summary["results_digest"] == golden["results_digest"]  # bit-identical, maps included
    assert summary["frames_in"] == summary["frames_out"] == 101 and summary["frames_dropped"] == 0
    assert {s for s in summary["stage_ms"] if summary["stage_ms"][s]} == {"read", "segmentation", "fft", "nfft",
                                                                         "detection"}


def test_summary_evaluates_against_the_ground_truth(clip_run):
    """The emulated clip carries the nose pixel and 3-D tip per frame: found within 5 px overall and per 5 cm of
    distance (0.35 to 0.70 m), as `tofd evaluate` bins them."""
    evaluation = clip_run[0]["evaluation"]
    frames = load_golden(GOLDEN)["frames"]
    errors = [math.dist(f["nose_px"], f["ground_truth_px"]) for f in frames]
    assert evaluation["frames"] == 101 and evaluation["radius_px"] == 5
    assert evaluation["found"] == sum(e <= 5 for e in errors)
    assert evaluation["max_error_px"] == round(max(errors), 3)
    assert evaluation["line"].startswith(f"nose found {evaluation['found']} of 101 within 5 px")
    per_distance = evaluation["per_distance"]
    assert list(per_distance) == ["0.35", "0.40", "0.45", "0.50", "0.55", "0.60", "0.65", "0.70"]
    assert sum(d["frames"] for d in per_distance.values()) == 101
    near = [e for f, e in zip(frames, errors, strict=True) if math.hypot(*f["ground_truth_xyz_m"]) < 0.375]
    assert per_distance["0.35"]["frames"] == len(near) and per_distance["0.35"]["max_error_px"] == round(max(near), 3)


def test_resume_skips_finished_partitions_and_redoes_a_missing_one(client, clip_run, tmp_path):
    summary, out = clip_run
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    Path(outputs(summary, copy)[2]).unlink()
    again = run(client, copy, [str(CLIP)], RunOptions(resume=True, progress=False))
    assert again["partitions"] == {"total": 5, "computed": 1, "resumed": 4, "failed": 0}
    assert again["results_digest"] == summary["results_digest"]


def test_killed_worker_costs_only_a_retry(client, clip_run, tmp_path):
    killed: list[int] = []
    stop = threading.Event()

    def kill_a_busy_worker() -> None:
        """From the start of the run, SIGKILL the first worker seen holding a partition (polled, so the kill
        does not depend on when a partition happens to finish)."""
        while not killed and not stop.is_set():
            busy = [w for w, keys in client.processing().items() if any(k.startswith("tofd-batch-") for k in keys)]
            if busy:
                pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            stop.wait(0.005)

    killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
    killer.start()
    try:
        summary = run(client, tmp_path, [str(CLIP)])
    finally:
        stop.set()
        killer.join(30)
    assert killed, "no worker was seen holding a partition"
    assert summary["partitions"]["failed"] == 0
    assert summary["results_digest"] == clip_run[0]["results_digest"]
    assert killed[0] not in {_pid(p) for p in outputs(summary, tmp_path)}  # what it held was redone elsewhere
    assert not list(tmp_path.glob("recording=*/*.tmp-*"))  # a write cut short leaves no file behind


def _pid(path: str) -> int:
    return json.loads(pq.read_schema(path).metadata[b"tofd.partition"])["pid"]


def test_bad_inputs_are_reported_and_do_not_stop_the_others(client, tmp_path):
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(CLIP.read_bytes())
    with open(CLIP, "rb") as f:
        index = frame_index(f)
    at = index.chunk_offsets[3] + 2000  # inside chunk 3's compressed records: its CRC fails
    data[at:at + 8] = b"\xff" * 8
    damaged.write_bytes(bytes(data))
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(CLIP.read_bytes()[:index.chunk_offsets[4] + 100])  # killed writer: no index, 4 frames
    foreign = tmp_path / "notes.mcap"
    foreign.write_text("not a recording")
    summary = run(client, tmp_path / "out", [str(damaged), str(truncated), str(foreign), str(tmp_path / "nope*.mcap")])
    by_name = {Path(e["input"]).name: e for e in summary["inputs"]}
    assert by_name["damaged.mcap"]["frames_out"] == 100 and by_name["damaged.mcap"]["status"] == "partial"
    assert "chunk 3" in by_name["damaged.mcap"]["errors"][0]
    assert summary["dropped_reasons"] == {"damaged": 1}
    assert by_name["truncated.mcap"]["indexed"] is False and by_name["truncated.mcap"]["frames_out"] == 4
    assert "truncated" in by_name["truncated.mcap"]["errors"][0]
    assert by_name["notes.mcap"]["status"] == "failed"
    assert by_name["nope*.mcap"]["errors"] == ["matches no recording"]


def test_cli_reports_a_missing_input_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tofd", "batch", str(tmp_path / "missing.mcap"), "--out",
                           str(tmp_path / "out"), "--workers", "1"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1
    assert "missing.mcap: no such file or directory" in proc.stderr
    assert "Traceback" not in proc.stderr
