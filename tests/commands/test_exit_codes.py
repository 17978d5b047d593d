"""Exit statuses and last lines as documented (`tofd --help`): an interrupted replay, a finished live run."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tofd.cli import _run, stop_signal_behind
from tofd_testing.chaos_helpers import default_stop_signals
from tofd_testing.pipeline_sources import write_config

ROOT = Path(__file__).resolve().parents[2]
CLIP = ROOT / "replay_data" / "emulated_face_035_070.mcap"


def _results_lines(out: Path) -> int:
    """Lines of the results file being written in `out` (under its temp name until the run finishes)."""
    return max((p.read_text().count("\n") for p in out.glob("*results.jsonl*")), default=0)


@pytest.mark.slow
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupted_replay_says_so_and_exits_128_plus_the_signal(tmp_path, sig, code):
    proc = subprocess.Popen([sys.executable, "-m", "tofd", "replay", CLIP, "--loop", "--rerun", "none", "--out",
                             tmp_path, "--config", write_config(tmp_path)], cwd=ROOT, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "RUST_LOG": "error"}, preexec_fn=default_stop_signals)
    try:
        deadline = time.monotonic() + 120
        while _results_lines(tmp_path) < 5 and time.monotonic() < deadline:
            time.sleep(0.2)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"tofd replay: interrupted by {sig.name} after ")
    summary = json.loads((tmp_path / "emulated_face_035_070.summary.json").read_text())
    assert summary["shutdown"]["reason"] == sig.name and summary["consistent"]
    assert last.endswith(f"after {summary['frames_out']} frames")  # --loop: no total


@pytest.mark.slow
def test_a_live_run_reports_its_drops_in_words(tmp_path):
    run = subprocess.run([sys.executable, "-m", "tofd", "run", "--emulate", "--frames", "30", "--health-port", "0",
                          "--config", write_config(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "RUST_LOG": "error"})
    assert run.returncode == 0, run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("tofd run: frames in ") and "{" not in last and "None" not in last
    assert "resource_tracker" not in run.stderr and "leaked" not in run.stderr


class _InterruptedField:
    """A class attribute whose __set_name__ meets a stop signal, as a dataclass field does when Ctrl-C lands while
    its module is loading."""

    def __set_name__(self, owner: type, name: str) -> None:
        raise KeyboardInterrupt


def _load_a_module_when_interrupted(args: argparse.Namespace) -> int:
    type("Loading", (), {"field": _InterruptedField()})
    return 0


def test_a_stop_signal_while_a_class_is_defined_is_an_interrupt_not_an_error(capsys):
    """Python 3.11 re-raises it as RuntimeError from the KeyboardInterrupt; tofd still exits 130 `interrupted`."""
    code = _run(argparse.Namespace(command="run", func=_load_a_module_when_interrupted))
    assert code == 130
    assert capsys.readouterr().err.strip() == "tofd run: interrupted"


def test_stop_signal_behind_finds_the_signal_only_where_there_is_one():
    with pytest.raises(BaseException) as caught:
        _load_a_module_when_interrupted(argparse.Namespace())
    assert isinstance(stop_signal_behind(caught.value), KeyboardInterrupt)
    assert stop_signal_behind(RuntimeError("a real failure")) is None


def _raises(exc: BaseException):
    def command(args: argparse.Namespace) -> int:
        raise exc

    return command


@pytest.mark.parametrize("exc, code", [
    ("tofd.drivers.errors:DriverError", 1), ("tofd.drivers.recording.format:FormatError", 2),
    ("tofd.drivers.bags.ros1_wire:WireError", 2), ("tofd.drivers.usb.protocol:ProtocolError", 1),
    ("tofd.lab.npz:NpzError", 2), ("tofd.algorithm.features:SamplingError", 2),
    ("tofd.service.pipeline:PipelineError", 1), ("tofd.service.viewer:ViewerError", 1),
    ("tofd.errors:UsageError", 2), ("tofd.drivers.bags.scan:BagError", 1)])
def test_every_error_is_a_tofd_error_printed_in_one_line_with_its_exit_status(capsys, exc, code):
    import importlib

    from tofd.errors import TofdError

    module, name = exc.split(":")
    cls = getattr(importlib.import_module(module), name)
    assert issubclass(cls, TofdError) and cls.exit_status == code
    assert _run(argparse.Namespace(command="replay", func=_raises(cls("the file ends at byte 12")))) == code
    assert capsys.readouterr().err == "tofd replay: the file ends at byte 12\n"


def test_value_errors_of_the_api_stay_value_errors():
    from tofd.algorithm.features import SamplingError
    from tofd.drivers.recording.format import FormatError
    from tofd.errors import UsageError

    assert all(issubclass(cls, ValueError) for cls in (SamplingError, FormatError, UsageError))


def test_an_os_error_is_a_runtime_failure_in_one_line(capsys):
    assert _run(argparse.Namespace(command="run", func=_raises(PermissionError(13, "Permission denied", "x")))) == 1
    assert capsys.readouterr().err == "tofd run: [Errno 13] Permission denied: 'x'\n"


@pytest.mark.parametrize(("args", "line"), [
    (["run", "--emulate", "--health-port", "99999"], "health.port: 99999 is not a TCP port (--health-port)"),
    (["run", "--emulate", "--health-port", "-1"], "health.port: -1 is not a TCP port (--health-port)"),
    (["run", "--emulate", "--rerun", "connect:notaurl"], "rerun.url: 'notaurl' is not a Rerun viewer's address"),
    (["run", "--emulate", "--rerun", "save:"], "rerun.path: empty"),
    (["replay", str(CLIP), "--rerun", "save:"], "rerun.path: empty"),
])
def test_a_bad_option_is_one_line_naming_the_key_and_the_option_exit_2(tmp_path, args, line):
    run = subprocess.run([sys.executable, "-m", "tofd", *args, "--config", write_config(tmp_path)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300, env={**os.environ, "RUST_LOG": "error"})
    assert run.returncode == 2, run.stderr
    (err,) = run.stderr.strip().splitlines()
    assert err.startswith(f"tofd {args[0]}: config error: ") and line in err, err
    assert list(tmp_path.glob("*.rrd")) == []


def test_the_config_file_and_the_option_say_the_same():
    from tofd.config import Config, ConfigError, config_from_dict, override

    with pytest.raises(ConfigError) as from_file:
        config_from_dict({"health": {"port": 99999}})
    with pytest.raises(ConfigError) as from_option:
        override(Config(), "health", "--health-port", port=99999)
    assert str(from_option.value) == f"{from_file.value} (--health-port)"


def test_an_experiment_without_its_extra_says_so_before_computing(tmp_path):
    out = tmp_path / "sphere"
    code = ("import sys; sys.modules['matplotlib'] = None  # as in an install without the lab extra\n"
            "from tofd.cli import main; sys.exit(main(sys.argv[1:]))")
    run = subprocess.run([sys.executable, "-c", code, "experiment", "sphere", "--out", str(out)], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and run.stderr.strip() == "tofd experiment: needs the 'lab' extra: pip install " \
                                                         "'tofd[lab]'", run.stderr
    assert not out.exists() and run.stdout == ""  # nothing computed, nothing written


@pytest.mark.slow
def test_a_busy_health_port_fails_before_the_viewer_replaces_an_earlier_rrd(tmp_path):
    import socket

    rrd = tmp_path / "live.rrd"
    rrd.write_bytes(b"an earlier run's complete recording")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = subprocess.run([sys.executable, "-m", "tofd", "run", "--emulate", "--frames", "5", "--health-port",
                              str(port), "--rerun", f"save:{rrd}", "--config", write_config(tmp_path)], cwd=ROOT,
                             capture_output=True, text=True, timeout=300, env={**os.environ, "RUST_LOG": "error"},
                             preexec_fn=default_stop_signals)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    assert run.stderr.strip().splitlines()[-1].startswith("tofd run: config error: health.port: cannot listen on")
    assert rrd.read_bytes() == b"an earlier run's complete recording"
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".rrd", ".tmp")) == ["live.rrd"]
