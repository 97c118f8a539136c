"""hilident.endings in this process: a signal becomes Interrupted once, a shield notes it, and a bus transaction
(uninterruptible) gets it only when it returns, never in the middle."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from hilident import endings
from hilident.errors import Interrupted

pytestmark = pytest.mark.skipif(
    threading.current_thread() is not threading.main_thread(), reason="signal handlers need the main thread"
)


def test_a_signal_within_a_transaction_is_raised_when_it_returns_not_in_it():
    lock = threading.Lock()
    steps = []
    with endings.signals_end_the_session():
        with pytest.raises(Interrupted) as caught:
            with endings.uninterruptible():
                with lock:  # what a library holds while a transaction runs
                    os.kill(os.getpid(), signal.SIGINT)
                    steps.append("rest of the transaction")
                steps.append("transaction returned")
            steps.append("never: raised at the block's end")
    assert steps == ["rest of the transaction", "transaction returned"]
    assert not lock.locked()  # released: the library's other threads can go on
    assert caught.value.signum == signal.SIGINT
    assert endings.received_signals() == [signal.SIGINT]


def test_within_a_shield_the_transaction_leaves_the_signal_to_the_shield():
    with endings.signals_end_the_session():
        with endings.shielded():
            with endings.uninterruptible():
                os.kill(os.getpid(), signal.SIGTERM)
            stopped = True  # the stop goes on: the outer shield decides when it is raised
        assert stopped
        with pytest.raises(Interrupted):
            endings.raise_pending()


def test_without_a_transaction_the_first_signal_raises_at_once_and_a_second_is_only_noted():
    with endings.signals_end_the_session():
        with pytest.raises(Interrupted):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs between bytecodes; this loop never ends normally
                pass
            pytest.fail("the signal was not raised")
        os.kill(os.getpid(), signal.SIGINT)  # a second one while stopping: noted
        endings.raise_pending()  # raised already once: nothing more
    assert endings.received_signals() == [signal.SIGINT, signal.SIGINT]
