"""`tofd batch` on a real Dask LocalCluster of 2 worker processes: the bundled clip in 5 partitions gives the
replay's results (its golden file, within the golden check's tolerances), and on this machine the same results
digest when a worker is killed mid-run or partitions are resumed; bad inputs."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
import threading
import zipfile
from dataclasses import replace
from pathlib import Path

import fsspec
import numpy as np
import pyarrow.parquet as pq
import pytest

from tofd.batch.golden import compare, load_golden
from tofd.batch.rows import frame_row, pipeline_fields
from tofd.batch.runner import CLUSTER_CONFIG, RunOptions, batch_client, prepare, read_rows, run_plan
from tofd.cli import main
from tofd.config import load_config
from tofd.drivers.frame import Frame, GroundTruth
from tofd.drivers.recording.index import frame_index
from tofd.lab.dataset import load_dataset, save_dataset, sidecar_path
from tofd.lab.evaluation import distance_bins
from tofd.lab.faces import generate
from tofd.process_setup import THREAD_ENV
from tofd.service.model import load_service_model
from tofd.service.pipeline.slots import local_slot
from tofd.service.pipeline.stages import FeatureStage, process_frame

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"
GOLDEN = ROOT / "replay_data" / "emulated_face_035_070.golden.json"
PARTITION = 25  # 101 frames -> 5 partitions
QUIET = RunOptions(progress=False)


@pytest.fixture(scope="module")
def client():
    with batch_client(None, 2) as c:
        yield c


def run(client, out: Path, inputs: list[str], options: RunOptions = QUIET, on_done=None,
        partition: int = PARTITION, evaluation: bool = True) -> dict:
    plans, job, digests = prepare(inputs, str(out), load_config(), partition, evaluation)
    return run_plan(client, plans, job, str(out), digests, options, on_done)


def outputs(summary: dict, out: Path, k: int = 0) -> list[str]:
    return [str(out / p) for p in summary["inputs"][k]["parts"]]


@pytest.fixture(scope="module")
def clip_run(client, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("batch")
    return run(client, out, [str(CLIP)]), out


def test_partitions_equal_the_replay(clip_run):
    summary, out = clip_run
    golden = load_golden(GOLDEN)  # what `tofd replay` gives (tests/batch/test_golden.py checks it on a real replay)
    assert summary["partitions"] == {"total": 5, "computed": 5, "resumed": 0, "failed": 0}
    assert len(list((out / "recording=emulated_face_035_070").glob("part-*.parquet"))) == 5
    rows = read_rows(outputs(summary, out))
    assert len(rows) == len(golden["frames"]) == 101
    assert [pipeline_fields(r).keys() for r in rows] == [f.keys() for f in golden["frames"]]
    report = compare(golden, [pipeline_fields(r) for r in rows])  # within the golden check's stated tolerances
    assert report.problems == () and report.frames_compared == 101
    assert report.bit_identical == (summary["results_digest"] == golden["results_digest"])  # reported, not required
    assert summary["frames_in"] == summary["frames_out"] == 101 and summary["frames_dropped"] == 0
    assert {s for s in summary["stage_ms"] if summary["stage_ms"][s]} == {"read", "segmentation", "fft", "nfft",
                                                                         "detection", "evaluation"}


def test_workers_compute_on_one_thread_with_the_cluster_settings(client, clip_run):
    """After a run every worker follows the thread rule (OpenCV's pool, the BLAS/OpenMP environment) and has the
    batch cluster's Dask settings (no profiler, slow monitors)."""

    def settings() -> tuple:
        import cv2
        import dask

        return (cv2.getNumThreads(), {k: os.environ.get(k) for k in THREAD_ENV},
                {k: dask.config.get(k) for k in CLUSTER_CONFIG})

    found = list(client.run(settings).values())
    assert len(found) == 2 and found == [(1, THREAD_ENV, CLUSTER_CONFIG)] * 2


def test_summary_evaluates_against_the_ground_truth(clip_run):
    """The emulated clip carries the nose pixel and 3-D tip per frame: found within 5 px overall and per 5 cm of
    distance (0.35 to 0.70 m), as `tofd evaluate` bins them."""
    evaluation = clip_run[0]["evaluation"]
    frames = load_golden(GOLDEN)["frames"]
    errors = [math.dist(f["tip_px"] or f["nose_px"], f["ground_truth_px"]) for f in frames]  # the answer: the tip
    assert evaluation["frames"] == 101 and evaluation["radius_px"] == 5
    assert evaluation["found"] == sum(e <= 5 for e in errors)
    assert evaluation["max_error_px"] == round(max(errors), 3)
    assert evaluation["line"].startswith(f"nose found {evaluation['found']} of 101 within 5 px")
    per_distance = evaluation["per_distance"]
    assert list(per_distance) == ["0.35", "0.40", "0.45", "0.50", "0.55", "0.60", "0.65", "0.70"]
    assert sum(d["frames"] for d in per_distance.values()) == 101
    near = [e for f, e in zip(frames, errors, strict=True) if math.hypot(*f["ground_truth_xyz_m"]) < 0.375]
    assert per_distance["0.35"]["frames"] == len(near) and per_distance["0.35"]["max_error_px"] == round(max(near), 3)


@pytest.fixture(scope="module")
def dataset_file(tmp_path_factory) -> Path:
    """10 frames of the rendered test split (0.35-0.70 m), saved as `tofd dataset generate` saves them."""
    return save_dataset(generate("test", 10, 3), tmp_path_factory.mktemp("dataset") / "faces.npz")


@pytest.fixture(scope="module")
def dataset_run(client, dataset_file, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("batch_dataset")
    return run(client, out, [str(dataset_file)], partition=4), out


def test_dataset_partitions_equal_the_whole_dataset_in_one_process(dataset_file, dataset_run):
    """A dataset .npz in 3 partitions of frame ranges gives the rows of its frames, with their labels as ground
    truth, run through the pipeline's per-frame code in this process."""
    summary, out = dataset_run
    assert summary["partitions"] == {"total": 3, "computed": 3, "resumed": 0, "failed": 0}
    assert summary["inputs"][0]["status"] == "ok" and summary["frames_out"] == 10
    ds = load_dataset(dataset_file)
    cfg = load_config()
    stage = FeatureStage(replace(cfg, intrinsics=ds.intrinsics), ds.intrinsics, load_service_model(cfg))
    slot = local_slot(ds.intrinsics.shape)
    tips = ds.nose_points()
    expected = []
    for i in range(len(ds)):
        truth = GroundTruth((float(ds.nose_px[i, 0]), float(ds.nose_px[i, 1])), bool(ds.nose_visible[i]),
                            tuple(map(float, tips[i])))
        frame = Frame(ds.range_m[i], ds.amplitude[i], i, 0, 0.0, 0.0, ds.intrinsics, ground_truth=truth)
        expected.append(pipeline_fields(frame_row(process_frame(stage, frame, slot))))
    assert [pipeline_fields(r) for r in read_rows(outputs(summary, out))] == expected
    evaluation = summary["evaluation"]
    visible = ds.nose_visible
    assert evaluation["frames"] == int(visible.sum())
    assert list(evaluation["per_distance"]) == [f"{d:.2f}" for d in np.unique(distance_bins(ds.distance_m[visible]))]


def test_summary_has_the_evaluate_tables_of_the_model_variants(client, tmp_path, capsys):
    """The batch summary's per-variant evaluation (from the eval_* columns of its rows, 2 partitions) is
    `tofd evaluate --model`'s on the same dataset (3 frames per distance; seed 5 has errors at 0.60 and 0.65 m):
    the same EER and answers tables, the same EERs and answers overall and per distance."""
    faces = save_dataset(generate("test", 24, 5), tmp_path / "faces.npz")
    summary = run(client, tmp_path / "batch", [str(faces)], partition=12)
    rows = read_rows(outputs(summary, tmp_path / "batch"))
    assert all(r["eval_has_nose"] is not None and math.isfinite(r["eval_false_min_nfft_range"]) for r in rows)
    model = ROOT / "config" / "nose_model.json"
    assert main(["evaluate", "--model", str(model), "--test", str(faces), "--workers", "1",
                 "--out", str(tmp_path / "evaluation")]) == 0
    printed = capsys.readouterr().out
    evaluation = summary["variant_evaluation"]
    assert evaluation["frames"] == 24
    assert evaluation["table"] in printed
    variant_rows = [line[:16].strip() for line in evaluation["table"].splitlines()[3:7]]
    assert variant_rows == ["FFT range", "FFT range+amp", "NFFT range", "NFFT range+amp"]  # the model's four
    expected = json.loads((tmp_path / "evaluation" / "evaluation.json").read_text())["results"]
    assert evaluation["results"] == {  # tofd evaluate's, less its table per identity
        name: {"overall": _without_points(r["overall"]),
               "per_distance": {d: _without_points(v) for d, v in r["per_distance"].items()}}
        for name, r in expected.items()}
    assert all("per_subject" in r for r in expected.values())
    assert any(r["overall"]["eer"] > 0 for r in expected.values())  # not only perfect separations compared
    plain = run(client, tmp_path / "plain", [str(faces)], partition=12, evaluation=False)  # tofd batch --no-evaluation
    assert plain["variant_evaluation"] is None and plain["results_digest"] == summary["results_digest"]
    assert plain["digests"]["run"] != summary["digests"]["run"]  # its partitions are not resumed as evaluated ones
    assert all(r["eval_has_nose"] is None for r in read_rows(outputs(plain, tmp_path / "plain")))


def _without_points(roc: dict) -> dict:
    return {k: v for k, v in roc.items() if k not in ("scale", "detection_rate", "false_positive_rate")}


def test_fsspec_urls_directories_and_globs(client, clip_run, dataset_file, dataset_run, tmp_path):
    """A memory:// directory holding a recording and a dataset (copied into the memory file system of this process
    and of every worker: it is per process), and a file:// glob, give the results of the local paths."""
    files = {"/archive/clip.mcap": CLIP.read_bytes(), "/archive/sub/faces.npz": dataset_file.read_bytes(),
             "/archive/sub/faces.json": sidecar_path(dataset_file).read_bytes()}
    _put_in_memory(files)
    client.run(_put_in_memory, files)
    summary = run(client, tmp_path / "memory", ["memory://archive/"], partition=4)
    digests = {Path(e["input"]).name: e["results_digest"] for e in summary["inputs"]}
    assert digests == {"clip.mcap": clip_run[0]["results_digest"], "faces.npz": dataset_run[0]["results_digest"]}
    summary = run(client, tmp_path / "file", [f"file://{dataset_file.parent}/*.npz"], partition=4)
    assert summary["results_digest"] == dataset_run[0]["results_digest"]


def _put_in_memory(files: dict[str, bytes]) -> None:
    fs = fsspec.filesystem("memory")
    for path, data in files.items():
        fs.pipe(path, data)


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
    assert not list(tmp_path.glob("recording=*/.*.tmp-*"))  # a write cut short leaves no file behind


def _pid(path: str) -> int:
    return json.loads(pq.read_schema(path).metadata[b"tofd.partition"])["pid"]


def test_bad_inputs_are_reported_and_do_not_stop_the_others(client, dataset_file, tmp_path):
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
    not_zip = tmp_path / "garbage.npz"
    not_zip.write_bytes(b"PK not really")
    unlabelled = tmp_path / "unlabelled.npz"
    with np.load(dataset_file) as npz:
        np.savez(unlabelled, **{k: npz[k] for k in npz.files if k != "nose_px"})
    damaged_dataset = tmp_path / "damaged_faces.npz"
    damaged_dataset.write_bytes(_zeroed_in_member(dataset_file, "range.npy"))
    summary = run(client, tmp_path / "out", [str(damaged), str(truncated), str(foreign), str(tmp_path / "nope*.mcap"),
                                             str(not_zip), str(unlabelled), str(damaged_dataset)])
    by_name = {Path(e["input"]).name: e for e in summary["inputs"]}
    assert by_name["damaged.mcap"]["frames_out"] == 100 and by_name["damaged.mcap"]["status"] == "partial"
    assert "chunk 3" in by_name["damaged.mcap"]["errors"][0]
    assert summary["dropped_reasons"] == {"damaged": 1}
    assert by_name["truncated.mcap"]["indexed"] is False and by_name["truncated.mcap"]["frames_out"] == 4
    assert "truncated" in by_name["truncated.mcap"]["errors"][0]
    assert by_name["notes.mcap"]["status"] == "failed"
    assert by_name["nope*.mcap"]["errors"] == ["matches no recording or dataset"]
    assert by_name["garbage.npz"]["status"] == "failed"
    assert "not a readable dataset" in by_name["garbage.npz"]["errors"][0]
    assert by_name["unlabelled.npz"]["errors"] == ["missing key(s) 'nose_px'"]
    assert by_name["damaged_faces.npz"]["errors"] == ["damaged archive: member 'range.npy' fails its CRC"]


def _zeroed_in_member(path: Path, member: str) -> bytes:
    """The bytes of a zip file with 64 bytes zeroed in the middle of one member's compressed data (the
    decompressor takes them; only the member's CRC shows the damage)."""
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:info.header_offset + 30])
    at = info.header_offset + 30 + name_len + extra_len + info.compress_size // 2
    data[at:at + 64] = bytes(64)
    return bytes(data)


def test_cli_reports_a_missing_input_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tofd", "batch", str(tmp_path / "missing.mcap"), "--out",
                           str(tmp_path / "out"), "--workers", "1"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2  # a data error
    assert "missing.mcap: no such file or directory" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_changed_row_layout_never_reuses_old_partitions(monkeypatch):
    """Partition names depend on the Parquet row schema, so --resume after a change of columns recomputes."""
    import pyarrow as pa

    from tofd.batch import rows
    from tofd.batch.plan import RESULT_SECTIONS, run_digests

    table = dict.fromkeys(RESULT_SECTIONS, {})
    before = run_digests(table, None)
    monkeypatch.setattr(rows, "ROW_SCHEMA", rows.ROW_SCHEMA.append(pa.field("new_column", pa.int64())))
    after = run_digests(table, None)
    assert before["config"] == after["config"] and before["model"] == after["model"]
    assert before["schema"] != after["schema"] and before["run"] != after["run"]
