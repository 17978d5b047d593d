"""StopSignals with real signals: recorded in order, the callback told which was first, handlers restored."""

import os
import signal

import pytest

from tofd.service.signals import StopSignals


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
