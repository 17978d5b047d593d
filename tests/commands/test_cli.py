"""The `tofd` command as a user meets it, in real processes: one line per ordinary mistake (exit 2 for usage and
data errors), nothing half-written, explicit model, replay checks, version, help and logging."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from tofd.cli import build_parser
from tofd_testing import HANG_GUARD_S

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def tofd(*args: str, cwd: Path | None = None, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "RERUN": "off", "RUST_LOG": "error"}
    return subprocess.run([sys.executable, "-m", "tofd", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=HANG_GUARD_S, env=env, **kwargs)


def one_line_error(proc: subprocess.CompletedProcess, code: int, *words: str) -> str:
    """The process failed with `code` and one stderr line naming `words`, without a traceback."""
    err = proc.stderr.strip()
    assert proc.returncode == code, (proc.returncode, err)
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for word in words:
        assert word in err, (word, err)
    return err


def test_version_and_help_describe_the_tool_not_the_source_tree():
    proc = tofd("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == "tofd 0.1.0"
    parser = build_parser()
    top = parser.format_help()
    assert "time-of-flight" in top and "Exit status" in top
    subparsers = next(a for a in parser._actions if a.choices and "run" in a.choices).choices
    for name, sub in subparsers.items():
        text = sub.format_help()
        assert "tofd/" not in text and ".py" not in text, (name, text)
    assert "lps, mp, mp_broad" in subparsers["evaluate"].format_help().replace("\n", " ").replace("  ", " ")


@pytest.mark.parametrize("kind", ["fifo", "zero", "binary", "directory"])
def test_config_that_is_no_config_file_is_one_line_exit_2(tmp_path, kind):
    path = {"fifo": tmp_path / "fifo.toml", "zero": Path("/dev/zero"), "binary": tmp_path / "bin.toml",
            "directory": tmp_path}[kind]
    if kind == "fifo":
        os.mkfifo(path)  # nobody ever writes: reading it would block forever
    if kind == "binary":
        path.write_bytes(bytes(range(256)) * 4)
    err = one_line_error(tofd("replay", str(CLIP), "--config", str(path), "--out", str(tmp_path / "o")), 2,
                         "config error", str(path))
    assert {"fifo": "not a regular file", "zero": "not a regular file", "binary": "not a UTF-8 text file",
            "directory": "not a regular file"}[kind] in err


def test_run_with_a_bad_serial_is_one_line_exit_2():
    one_line_error(tofd("run", "--emulate", "--serial", "zz"), 2, "--serial", "'zz' is not 8 hex digits")


def test_sigterm_while_the_emulated_scene_is_prepared_exits_cleanly(tmp_path):
    env = {**os.environ, "RERUN": "off"}
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "run", "--emulate", "--rerun", "none", "--health-port",
                             "0", "--summary", str(tmp_path / "s.json")], stderr=subprocess.PIPE, text=True, env=env)
    guard = threading.Timer(HANG_GUARD_S, proc.kill)  # a missed line must not block the suite forever
    guard.start()
    try:
        for line in proc.stderr:  # wait until it is preparing the scene
            if "rendering the emulated camera" in line:
                break
        proc.send_signal(signal.SIGTERM)
        rest = proc.stderr.read()
        assert proc.wait(HANG_GUARD_S) == 0
    finally:
        guard.cancel()
        proc.kill()
        proc.wait()
    assert "Traceback" not in rest and "SIGTERM before the camera was ready" in rest, rest


def _bad_npz(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / f"{kind}.npz"
    if kind == "text":
        path.write_text("not numpy\n")
    elif kind == "no_nose":
        np.savez(path, range=np.zeros((2, 144, 176), np.float32), amplitude=np.zeros((2, 144, 176), np.float32))
    elif kind in ("shape", "pickle", "sidecar_extra_key"):
        keys = {"nose_px": np.zeros((2, 2)), "nose_visible": np.ones(2, bool), "distance_m": np.ones(2),
                "yaw_deg": np.zeros(2), "pitch_deg": np.zeros(2), "subject": np.array(["a", "b"])}
        rng = np.zeros((2, 10, 10), np.float32) if kind != "pickle" else np.array([{"a": 1}, None], dtype=object)
        np.savez(path, range=rng, amplitude=np.zeros((2, 10, 10), np.float32), **keys)
    if kind == "sidecar_extra_key":  # the intrinsics fit the planes, but with a key Intrinsics does not have
        intrinsics = {"width": 10, "height": 10, "fx": 20.0, "fy": 20.0, "cx": 4.5, "cy": 4.5, "skew": 0.0}
        path.with_suffix(".json").write_text(json.dumps({"intrinsics": intrinsics}))
    return path


@pytest.mark.parametrize("kind,words", [("missing", ["no such dataset file"]), ("text", ["not a dataset .npz"]),
                                        ("no_nose", ["missing key", "'nose_px'"]), ("shape", ["shape (2, 10, 10)"]),
                                        ("pickle", ["'range'", "without pickle"]),
                                        ("sidecar_extra_key", ["sidecar_extra_key.json", "skew"])])
def test_evaluate_with_a_bad_test_file_fails_before_any_training(tmp_path, kind, words):
    path = _bad_npz(tmp_path, kind)
    proc = tofd("evaluate", "--test", str(path), "--out", str(tmp_path / "ev"))
    one_line_error(proc, 2, str(path.with_suffix("")), *words)  # the .npz, or its .json sidecar
    assert "rendering train" not in proc.stderr and not (tmp_path / "ev").exists()  # nothing left behind


def test_train_needs_an_explicit_out_and_names_a_missing_train_file(tmp_path):
    assert tofd("train", "--train-frames", "1").returncode == 2  # argparse: --out is required
    one_line_error(tofd("train", "--train", str(tmp_path / "absent.npz"), "--out", str(tmp_path / "m.json")), 2,
                   "absent.npz")
    one_line_error(tofd("evaluate", "--test-subjects", "bob", "--out", str(tmp_path / "e")), 2, "bob")
    one_line_error(tofd("train", "--train-frames", "1", "--out", str(tmp_path / "no" / "dir" / "m.json")), 2,
                   "does not exist")


@pytest.mark.parametrize("kind", ["existing_file", "parent_is_a_file", "dangling_symlink"])
def test_replay_out_that_cannot_be_a_directory_is_one_line_exit_2(tmp_path, kind):
    target = tmp_path / "target"
    if kind == "existing_file":
        target.write_text("keep me\n")
    elif kind == "parent_is_a_file":
        (tmp_path / "file").write_text("keep me\n")
        target = tmp_path / "file" / "out"
    else:
        target.symlink_to(tmp_path / "nowhere")
    one_line_error(tofd("replay", str(CLIP), "--out", str(target)), 2, "--out", str(target))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"existing_file": ["target"], "dangling_symlink":
                                                                 ["target"], "parent_is_a_file": ["file"]}[kind])


def test_replay_argument_mistakes(tmp_path):
    one_line_error(tofd("replay", str(CLIP), "--speed", "2", "--out", str(tmp_path)), 2, "--speed needs --realtime")
    err = one_line_error(tofd("replay", str(CLIP), "--seek", "100000", "--out", str(tmp_path)), 2, "--seek 100000",
                         "past the end")
    assert err.count(CLIP.name) == 1, err
    one_line_error(tofd("replay", str(tmp_path / "absent.mcap"), "--out", str(tmp_path)), 2, "absent.mcap")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("kind", ["invalid_json", "not_utf8", "not_a_model", "directory"])
def test_a_model_file_that_cannot_be_used_stops_replay_with_exit_2_naming_it(tmp_path, kind):
    model = tmp_path / "nose_model.json"
    if kind == "directory":
        model.mkdir()
    else:
        model.write_bytes({"invalid_json": b"{ not json", "not_utf8": b'{"format": "\xff"}',
                           "not_a_model": b'{"format": "other"}'}[kind])
    config = tmp_path / "tofd.toml"
    config.write_text(f'[detector]\nmodel_path = "{model}"\n')
    proc = tofd("replay", str(CLIP), "--config", str(config), "--out", str(tmp_path / "o"), "--rerun", "none")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]  # after the INFO line naming the model (not for the directory)
    assert last.startswith("tofd replay: config error: detector.model_path: ") and str(model) in last, last
    assert {"invalid_json": "invalid JSON", "not_utf8": "invalid JSON", "not_a_model": "key 'format' is 'other'",
            "directory": "cannot read"}[kind] in last


def test_replay_uses_the_configured_model_not_one_in_the_cwd_and_reports_accuracy(tmp_path):
    (tmp_path / "nose_model.json").write_text("{ not the model the config names")  # a stray trained model
    out = tmp_path / "out"
    proc = tofd("replay", str(CLIP), "--out", str(out), "--frames", "12", "--rerun", "none", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    # the bundled model as the tofd that ran resolves it from cwd=tmp_path: config/ of a source checkout, the
    # installed tofd/defaults/ of a non-editable install
    shipped = Path(subprocess.run([sys.executable, "-c", "from tofd.config import default_file; "
                                   "print(default_file('nose_model.json'))"], cwd=tmp_path, capture_output=True,
                                  text=True, check=True).stdout.strip())
    assert shipped.read_bytes() == (ROOT / "config" / "nose_model.json").read_bytes()
    summary = json.loads((out / "emulated_face_035_070.summary.json").read_text())
    import hashlib

    assert summary["model"] == {"path": str(shipped), "sha256": hashlib.sha256(shipped.read_bytes()).hexdigest()}
    assert len(summary["config_sha256"]) == 64
    assert f"INFO model: {shipped}" in proc.stderr  # printed at start, with its level
    assert "nose found 12 of 12 within 5 px; median error" in proc.stderr and "; track found " in proc.stderr
    assert (out / "emulated_face_035_070.accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(out.glob(".*.tmp"))


@pytest.mark.slow
def test_replay_loop_results_carry_the_loop_index(tmp_path):
    proc = tofd("replay", str(CLIP), "--out", str(tmp_path), "--loop", "--frames", "110", "--rerun", "none")
    assert proc.returncode == 0, proc.stderr
    rows = [json.loads(x) for x in (tmp_path / "emulated_face_035_070.results.jsonl").read_text().splitlines()]
    loops = [r["loop"] for r in rows]
    assert loops == sorted(loops) and set(loops) == {0, 1} and len(rows) == 110
    first = [r["frame_counter"] for r in rows if r["loop"] == 0]
    assert first == sorted(first) and rows[-1]["frame_counter"] < first[-1]


def test_log_lines_carry_their_level_and_a_journal_priority_under_systemd(tmp_path):
    """On a terminal `tofd: LEVEL message`; when stderr is the journal stream systemd announced ($JOURNAL_STREAM
    = device:inode of stderr), each line starts with its syslog priority so `journalctl -p warning` filters."""
    code = ("import logging; from tofd.logs import setup_logging; setup_logging('info'); "
            "log = logging.getLogger('tofd.x'); log.info('hello'); log.warning('careful'); log.debug('hidden')")
    err_path = tmp_path / "stderr"
    for journal in (False, True):
        with open(err_path, "w") as err:
            st = os.fstat(err.fileno())
            env = {**os.environ, "JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}" if journal else ""}
            subprocess.run([sys.executable, "-c", code], stderr=err, env=env, timeout=HANG_GUARD_S, check=True)
        lines = err_path.read_text().splitlines()
        if journal:
            assert lines == ["<6>INFO tofd.x: hello", "<4>WARNING tofd.x: careful"], lines
        else:
            assert lines == ["tofd: INFO hello", "tofd: WARNING careful"], lines


def test_help_and_version_import_no_command_module():
    """`tofd --help` lists every command from its docstring without importing the commands (their imports are slow)."""
    code = ("import sys, contextlib, io; from tofd.cli import main\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()) as out: main(['--help'])\n"
            "assert 'replay' in out.getvalue() and 'import' in out.getvalue()\n"
            "heavy = ('tofd.commands.', 'tofd.service', 'rerun', 'scipy')\n"
            "print(sorted(m for m in sys.modules if m.startswith(heavy)))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]", proc.stdout
