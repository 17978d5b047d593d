"""Signals: StopSignals with real signals (recorded in order, the callback told which was first, handlers
restored), and a real `tofd run` sent SIGUSR1, SIGHUP, SIGQUIT and Ctrl-C at every moment of its start-up."""

import json
import os
import signal
import time

import pytest

from tofd.service import signals
from tofd.service.signals import StopSignals
from tofd_testing.chaos_helpers import alive, health_port, tofd, workers_of
from tofd_testing.pipeline_sources import write_config


@pytest.fixture(autouse=True)
def as_under_a_terminal(monkeypatch):
    """StopSignals in this process handles every stop signal, as when started from a terminal, however pytest was
    started (under nohup SIGHUP is ignored, in the background SIGINT and SIGQUIT: kept ignored by design)."""
    monkeypatch.setattr(signals, "_IGNORED_AT_START", frozenset())
    monkeypatch.setattr(StopSignals, "SIGNALS", signals.STOP_SIGNALS)


def test_signals_are_recorded_passed_on_and_the_previous_handlers_come_back():
    before = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}
    calls = []
    with StopSignals(lambda signum, first: calls.append((signum, first))) as stop:
        assert not stop and stop.name == ""
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)
    assert calls == [(signal.SIGTERM, True), (signal.SIGINT, False)]
    assert stop and stop.name == "SIGTERM" and stop.received == [signal.SIGTERM, signal.SIGINT]
    assert stop.first_at_s is not None
    assert {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS} == before


def test_an_exception_raised_by_the_callback_ends_the_block_and_restores_the_handlers():
    before = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}

    def refuse(signum: int, _first: bool) -> None:
        raise InterruptedError(signal.Signals(signum).name)

    with pytest.raises(InterruptedError, match="SIGINT"), StopSignals(refuse):
        os.kill(os.getpid(), signal.SIGINT)
        pytest.fail("the signal did not interrupt the block")
    assert {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS} == before


def test_sighup_and_sigquit_stop_and_sigusr1_asks_for_a_status_line():
    with StopSignals() as stop:
        os.kill(os.getpid(), signal.SIGUSR1)
        os.kill(os.getpid(), signal.SIGUSR1)
        assert not stop and stop.status_requests == 2
        os.kill(os.getpid(), signal.SIGHUP)
        os.kill(os.getpid(), signal.SIGQUIT)
    assert stop.received == [signal.SIGHUP, signal.SIGQUIT] and stop.name == "SIGHUP"


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGQUIT])
def test_a_running_daemon_logs_its_status_on_sigusr1_and_drains_on_sighup_or_sigquit(tmp_path, sig):
    summary_path = tmp_path / "summary.json"
    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--health-port", "0", "--summary",
                summary_path, "--rerun", "none", start_new_session=True)
    try:
        _, lines = health_port(proc)
        deadline = time.monotonic() + 60
        while not (workers := workers_of(proc.pid)) and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(1.0)  # some frames
        os.killpg(proc.pid, signal.SIGUSR1)  # the whole group, as a terminal would send it
        while not any("INFO status:" in line for line in lines):
            lines.append(proc.stderr.readline())
            assert lines[-1], "".join(lines)
        assert proc.poll() is None and workers and all(alive(pid) for pid in workers)
        os.killpg(proc.pid, sig)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0, "".join(lines) + err
    summary = json.loads(summary_path.read_text())
    assert summary["shutdown"]["reason"] == signal.Signals(sig).name and summary["consistent"]
    assert summary["frames_out"] > 0 and summary["worker_restarts"] == 0, summary
    assert "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.3, 0.8, 1.5, 3.0])
def test_ctrl_c_at_any_moment_of_start_up_exits_as_documented_without_a_traceback(tmp_path, delay_s):
    """SIGINT to the whole process group (a terminal's Ctrl-C) while tofd loads (130, `interrupted`), opens the
    camera (0, `stopped`) or starts its children (0, drained with a summary). (Within the interpreter's own
    start-up, before any code of tofd runs, Python answers for itself.)"""
    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--health-port", "0", "--rerun", "none",
                start_new_session=True)
    time.sleep(delay_s)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert "Traceback" not in err, err
    if proc.returncode == 130:
        assert err.strip().splitlines()[-1].startswith("tofd") and "interrupted (SIGINT)" in err, err
    else:
        assert proc.returncode == 0, err
        last = err.strip().splitlines()[-1]
        assert "before the camera was ready; stopped" in last or last.startswith("tofd run: frames in"), err


@pytest.mark.slow
def test_a_daemon_started_with_sighup_ignored_as_under_nohup_keeps_ignoring_it(tmp_path):
    proc = tofd("run", "--emulate", "--config", write_config(tmp_path), "--health-port", "0", "--rerun", "none",
                preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN))
    try:
        _, lines = health_port(proc)
        proc.send_signal(signal.SIGHUP)
        time.sleep(2)
        assert proc.poll() is None, "".join(lines)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "Traceback" not in err, err
