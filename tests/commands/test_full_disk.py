"""Outputs on a real full filesystem (a tmpfs of a few MB, mounted here as root; skipped where mounting is not
permitted): a replay and a live run whose outputs die of ENOSPC say so once per output, in /healthz (degraded),
/metrics and the summary, leave no file under its final name that is not complete and no temp file."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tofd_testing.chaos_helpers import health_port, healthz, metric, metrics, tofd
from tofd_testing.pipeline_sources import PATIENT_VIEWER, bundled_config, write_config

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MB tmpfs at tmp_path/disk (unmounted after)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)], capture_output=True,
                          text=True)
    if proc.returncode != 0:
        pytest.skip(f"mounting a tmpfs is not permitted here: {proc.stderr.strip()}")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.rglob("*") if p.name.endswith(".tmp"))


@pytest.mark.slow
def test_a_replay_onto_a_full_disk_names_each_failed_output_once_and_leaves_no_temp_file(small_disk):
    out = small_disk / "out"
    # the .rrd sent frame by frame: it fills the disk while the pipeline, which waits for the viewer, is at most a
    # few frames ahead, so the results file cannot have been finished first
    proc = tofd("replay", CLIP, "--out", out, "--frames", "60", "--config",
                bundled_config(small_disk.parent / "tofd.toml", pipeline=PATIENT_VIEWER, rerun={"batch_frames": 1}))
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1, err
    lines = [line for line in err.strip().splitlines()  # not ours: multiprocessing's semaphore warning at exit
             if "resource_tracker" not in line and "warnings.warn" not in line]
    assert "Traceback" not in err and len(lines) <= 5, err
    for name in ("results.jsonl", "rrd"):
        path = out / f"emulated_face_035_070.{name}"
        assert not path.exists()  # never complete: never under its final name
        assert sum(f"output {path} " in line for line in err.splitlines()) == 1, err
    assert _leftovers(out) == []
    assert "failed: " in lines[-1] and "results.jsonl" in lines[-1], err


@pytest.mark.slow
def test_a_live_save_sink_that_fills_its_disk_shows_in_healthz_metrics_and_the_summary(small_disk, tmp_path):
    rrd, summary_path = small_disk / "live.rrd", tmp_path / "summary.json"
    config = write_config(tmp_path, pipeline=PATIENT_VIEWER, rerun={"rotate_mb": 0.0})  # one file, not segments
    proc = tofd("run", "--emulate", "--config", config, "--rerun", f"save:{rrd}", "--health-port", "0", "--summary",
                summary_path)
    try:
        port, lines = health_port(proc)
        deadline, status = time.monotonic() + 120, {}
        while status.get("status") != "degraded" and time.monotonic() < deadline:
            time.sleep(0.5)
            code, status = healthz(port)
        assert code == 200 and status["status"] == "degraded", status
        assert any(str(rrd) in problem and "No space left" in problem for problem in status["problems"]), status
        assert metric(metrics(port), "tofd_output_failed", f'{{output="{rrd}"}}') == 1
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    err = "".join(lines) + err
    assert proc.returncode == 1 and "Traceback" not in err, err
    summary = json.loads(summary_path.read_text())
    assert str(rrd) in summary["outputs_failed"] and summary["consistent"], summary
    assert not rrd.exists() and _leftovers(small_disk) == []
    assert (small_disk / "live.partial.rrd").exists()


def _fill(disk: Path) -> None:
    """Write a file that takes every free byte of `disk`."""
    with open(disk / "filler", "wb") as f:
        try:
            while True:
                f.write(bytes(64 << 10))
                f.flush()
        except OSError:
            pass


def test_an_export_onto_a_full_disk_leaves_the_earlier_complete_outputs_intact(small_disk):
    import numpy as np

    out = small_disk / "out"
    for to, frames in (("npz", "0:3"), ("ply", "0:1"), ("png", "0:1")):
        proc = tofd("export", CLIP, "--to", to, "--frames", frames, "--out", out)
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert len(before) == 4  # the .npz, one .ply, a range and an amplitude .png
    _fill(small_disk)
    for to, frames in (("npz", "0:60"), ("ply", "0:1"), ("png", "0:1")):
        proc = tofd("export", CLIP, "--to", to, "--frames", frames, "--out", out)
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 1 and "No space left" in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1, err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing replaced, nothing left behind
    with np.load(out / "emulated_face_035_070.npz") as npz:
        assert npz["range_m"].shape[0] == 3


def test_a_replay_onto_a_nearly_full_disk_is_refused_at_once_naming_the_rrd(small_disk):
    """A disk with a few kB free: Rerun's file writer cannot write the recording's first bytes and its save() would
    wait for it for ever (the viewer process then "did not start in 30 s"); the replay is refused before it starts,
    naming the .rrd and the full disk, and leaves nothing behind."""
    out = small_disk / "out"
    out.mkdir()
    _fill(small_disk)
    filler = small_disk / "filler"
    os.truncate(filler, filler.stat().st_size - (16 << 10))  # 16 kB free
    proc = tofd("replay", CLIP, "--out", out)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert f"output {out / 'emulated_face_035_070.rrd'} failed: No space left on device" in last, err
    assert "did not start" not in err
    assert list(out.iterdir()) == []
