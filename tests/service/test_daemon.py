"""`tofd run` and `tofd replay` as real subprocesses: SIGTERM drains and exits 0, sd_notify, outputs complete."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tofd.config import load_config
from tofd.drivers.recording.reader import read_recording_info
from tofd.service.viewer import blueprint as bp
from tofd_testing.chaos_helpers import children_of
from tofd_testing.pipeline_sources import PATIENT_VIEWER, dropped_frames, write_config
from tofd_testing.rrd_helpers import check_rrd, has_footer

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def tofd(*args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "tofd", *map(str, args)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # a live run writes none, on purpose
def test_run_emulated_sigterm_drains_and_exits_zero(tmp_path):
    notify = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(notify))
    sock.settimeout(60)
    env = {key: value for key, value in os.environ.items() if key != "RUST_LOG"}
    env.update(NOTIFY_SOCKET=str(notify), WATCHDOG_USEC="400000")
    rrd, summary_path = tmp_path / "live.rrd", tmp_path / "summary.json"
    config = write_config(tmp_path, pipeline=PATIENT_VIEWER, rerun={"rotate_mb": 0.0})  # one file, not segments
    proc = tofd("run", "--emulate", "--config", config, "--rerun", f"save:{rrd}", "--health-port", "0",
                "--summary", summary_path, env=env)
    try:
        messages = []
        while "READY=1" not in messages:
            messages.append(sock.recv(100).decode())
        t_ready = time.monotonic()
        while "WATCHDOG=1" not in messages or time.monotonic() - t_ready < 2.0:  # ~60 frames at 30 fps
            messages.append(sock.recv(100).decode())
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=300)  # a hang guard
    finally:
        proc.kill()
        sock.close()
    assert proc.returncode == 0, err
    summary = json.loads(summary_path.read_text())
    assert summary["consistent"] and summary["frames_pending"] == 0, summary
    assert summary["frames_in"] == summary["frames_out"] + summary["frames_dropped"]
    assert summary["frames_out"] >= 10 and summary["error"] is None
    assert "frames in" in err
    logged = check_rrd(rrd, None)[bp.RANGE][1].column("frame").to_pylist()
    # the viewer is best effort: a delivered frame it could not take (a full hand-off, under load) is counted
    assert len(logged) + summary["viewer_dropped"] == summary["frames_out"] and logged == sorted(set(logged))
    assert summary["viewer"]["exit"] == "clean" and summary["shutdown"]["abandoned"] == []
    assert set(logged).isdisjoint(d["frame_counter"] for d in dropped_frames(summary))
    # no footer: the SDK would hold its chunk index in memory for as long as a live run lasts (and says nothing)
    assert not has_footer(rrd) and "footer" not in err


@pytest.mark.slow
def test_replay_writes_results_and_rrd_for_every_frame(tmp_path):
    """Every frame in the results and the .rrd; a replay that reached its end gives the viewer finish_timeout_s to
    finish its file, not the SIGTERM budget (here half a second, too short for a viewer on busy cores)."""
    n = read_recording_info(CLIP).frame_count
    proc = tofd("replay", CLIP, "--out", tmp_path, "--config",
                write_config(tmp_path, pipeline={"shutdown_timeout_s": 0.5}), env={**os.environ, "RUST_LOG": "error"})
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert f"tofd replay: {n} frames processed, 0 dropped" in err
    stem = CLIP.name.split(".")[0]
    lines = [json.loads(x) for x in (tmp_path / f"{stem}.results.jsonl").read_text().splitlines()]
    counters = [x["frame_counter"] for x in lines]
    assert len(lines) == n and counters == sorted(counters)
    accepted = [x for x in lines if x["accepted"]]
    assert accepted and all(len(x["nose_px"]) == 2 and x["score"] <= 1.5 for x in accepted)
    summary = json.loads((tmp_path / f"{stem}.summary.json").read_text())
    assert summary["frames_out"] == n and summary["frames_dropped"] == 0 and summary["consistent"]
    shutdown = summary["shutdown"]
    assert shutdown["reason"] == "end" and shutdown["budget_s"] == load_config().pipeline.finish_timeout_s
    assert summary["viewer"]["exit"] == "clean" and not shutdown["abandoned"]
    tables = check_rrd(tmp_path / f"{stem}.rrd", counters)
    assert has_footer(tmp_path / f"{stem}.rrd")  # a replay ends: its file keeps the index for random access
    nose = tables[bp.NOSE_2D][1]
    logged = dict(zip(nose.column("frame").to_pylist(), nose.column("Points2D:positions").to_pylist(), strict=True))
    for x in accepted:  # the detected nose's refined tip is what the viewer shows, its origin at the pixel's corner
        assert logged[x["frame_counter"]] == [pytest.approx([c + 0.5 for c in x["tip_px"]], abs=0.006)]
    # beside it the track, through the viewer process's wire format: its box where the results put it
    confirmed = [x for x in lines if x["track"]["status"] == "tracking"]
    assert confirmed and all(x["track"]["nose_px"] is not None for x in confirmed)
    tracked = [x for x in lines if x["track"]["nose_px"] is not None]  # confirmed, or new and associated
    assert summary["track"]["tracked_frames"] == len(tracked)
    assert summary["track"]["detected_frames"] == len(accepted) and summary["track"]["acquired"] >= 1
    boxes = tables[bp.TRACK_2D][1]
    centers = dict(zip(boxes.column("frame").to_pylist(), boxes.column("Boxes2D:centers").to_pylist(), strict=True))
    assert set(centers) == set(counters)
    for x in lines:
        want = x["track"]["nose_px"]
        assert centers[x["frame_counter"]] == ([pytest.approx([c + 0.5 for c in want], abs=0.01)] if want else [])


def test_replay_of_a_missing_file_is_a_one_line_error(tmp_path):
    proc = tofd("replay", tmp_path / "nope.mcap", "--out", tmp_path)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "nope.mcap" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("sink", ["none", "save"])
def test_sigterm_while_the_viewer_and_workers_start_exits_zero_with_a_summary(tmp_path, sink):
    """A stop signal while the viewer process or the workers start is not held until they are ready: nothing
    is captured, the summary says why it stopped."""
    summary_path = tmp_path / "summary.json"
    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--health-port", "0", "--summary",
                summary_path, "--rerun", "none" if sink == "none" else f"save:{tmp_path / 'x.rrd'}",
                env={**os.environ, "RUST_LOG": "error"})
    try:
        lines = []
        while not any("INFO model:" in line for line in lines):  # logged once the stop signal is ours
            lines.append(proc.stderr.readline())
            assert lines[-1], "".join(lines)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)  # a hang guard
    finally:
        proc.kill()
    assert proc.returncode == 0, "".join(lines) + err
    summary = json.loads(summary_path.read_text())
    assert summary["frames_in"] == 0 and summary["consistent"] and summary["shutdown"]["reason"] == "SIGTERM"
    if sink == "save":
        assert summary["viewer"] == {"exit": "cancelled", "unsent": 0}


def viewer_of(pid: int) -> int | None:
    """The viewer child of a tofd process: the child that maps the viewer's shared-memory slot ring."""
    for kid in children_of(pid):
        try:
            if f"/dev/shm/tofd_{pid}_viewer_" in Path(f"/proc/{kid}/maps").read_text():
                return kid
        except OSError:
            continue
    return None


@pytest.mark.slow
def test_a_replay_waits_for_a_slow_viewer_and_loses_no_frame_of_its_rrd(tmp_path):
    """A lossless replay whose viewer takes no frame for several times the SIGTERM budget (stopped, as a niced
    viewer on busy cores can be) waits for it: every frame in the .rrd, no viewer drop."""
    n = read_recording_info(CLIP).frame_count
    proc = tofd("replay", CLIP, "--out", tmp_path, "--config",
                write_config(tmp_path, pipeline={"shutdown_timeout_s": 0.5}), env={**os.environ, "RUST_LOG": "error"})
    stopped = None
    try:
        deadline = time.monotonic() + 120
        while (stopped := viewer_of(proc.pid)) is None and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert stopped is not None, "no viewer child"
        while not any(p.stat().st_size for p in tmp_path.glob("*results.jsonl*")) and time.monotonic() < deadline:
            time.sleep(0.01)  # until frames flow (the results file grows under a temp name)
        os.kill(stopped, signal.SIGSTOP)
        time.sleep(3.0)  # six SIGTERM budgets
        os.kill(stopped, signal.SIGCONT)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    stem = CLIP.name.split(".")[0]
    summary = json.loads((tmp_path / f"{stem}.summary.json").read_text())
    assert summary["viewer_dropped"] == 0 and summary["frames_out"] == n, summary
    counters = [json.loads(x)["frame_counter"] for x in (tmp_path / f"{stem}.results.jsonl").read_text().splitlines()]
    check_rrd(tmp_path / f"{stem}.rrd", counters)
