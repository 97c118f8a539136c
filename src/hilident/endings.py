"""How a session ends: signals become one exception, once, and the stopping cannot be interrupted.

A bench run can end in many ways: normally, on an error, on Ctrl-C (once or
twice in quick succession), on SIGTERM (``systemctl stop``, a CI timeout) or
SIGHUP (the terminal was closed). :func:`signals_end_the_session` turns the
first of these signals into :class:`~hilident.errors.Interrupted` raised in the
main thread, where the session's ``finally`` blocks command the device safe
and close the recordings. Inside :func:`shielded` (the stopping itself) a
signal is noted but not raised, so a second Ctrl-C cannot cut the stop or the
file's closing short; :func:`raise_pending` raises it at the next safe point.
Inside :func:`uninterruptible` (a bus transaction whose library holds locks
its own threads need) a signal is raised when the transaction returns.

The exit code of an interrupted session is ``128 + signal`` (SIGHUP 129,
SIGINT 130, SIGTERM 143), as a shell reports a process killed by it.
"""

from __future__ import annotations

import contextlib
import signal
import threading

from hilident.errors import Interrupted

#: Signals that end a session cleanly (SIGKILL cannot be caught: the device's own net stops the axis).
ENDING_SIGNALS = tuple(s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None)


class _State:
    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """No signal received, none raised, no shield up."""
        self.received: list[int] = []
        self.raised = False
        self.shield_depth = 0


_state = _State()


def _on_signal(signum, frame) -> None:
    _state.received.append(signum)
    if _state.raised or _state.shield_depth:
        return  # already stopping: noted, not raised
    _state.raised = True
    raise Interrupted(signum)


@contextlib.contextmanager
def signals_end_the_session():
    """Within this block, SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` once.

    Signals the process ignores (``nohup`` ignores SIGHUP) stay ignored.

    Only the main thread can install signal handlers; elsewhere (a test
    running a session in a thread) the block changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    # a signal the process was started ignoring stays ignored (``nohup`` ignores SIGHUP; a shell's
    # background job, SIGINT): ending the session on it would undo what the user asked for
    previous = {s: h for s in ENDING_SIGNALS if (h := signal.getsignal(s)) is not signal.SIG_IGN}
    _state.reset()
    for s in previous:
        signal.signal(s, _on_signal)
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def ignore_further_signals() -> None:
    """For a process on its way out after a signal ended its session: a late second Ctrl-C must not turn
    the documented exit code into a death by signal."""
    if threading.current_thread() is threading.main_thread():
        for s in ENDING_SIGNALS:
            signal.signal(s, signal.SIG_IGN)


@contextlib.contextmanager
def shielded():
    """A block that must run to its end (stop the axis, close the files): signals are only noted.

    It never raises a signal itself, so it can run in ``except`` and
    ``finally`` blocks without replacing the error that is ending the session
    (the first cause wins); :func:`raise_pending` raises a noted one at the
    next point where the session may stop.
    """
    _state.shield_depth += 1
    try:
        yield
    finally:
        _state.shield_depth -= 1


@contextlib.contextmanager
def uninterruptible():
    """A library call that must not be cut in the middle, with a signal that came during it raised at its end.

    A signal's exception can land between a lock's acquire and the ``try``
    that releases it, in code not written for that (CPython cannot make a
    ``with lock:`` safe against it). canopen's SDO client then keeps its
    response queue locked, and its receiving thread blocks on it for good:
    the Disable Voltage of the stop that follows would wait for an answer
    that is never handed over. Such calls run in this block: a signal is
    noted while they run and raised as soon as they return (or by
    :func:`raise_pending` later, when the call itself raised).
    """
    with shielded():
        yield
    raise_pending()


def raise_pending() -> None:
    """Raise :class:`Interrupted` for a signal noted in a shielded block and not raised yet."""
    if not _state.shield_depth and _state.received and not _state.raised:
        _state.raised = True
        raise Interrupted(_state.received[0])


def received_signals() -> list[int]:
    """Signals received since the session began (the first one ended it)."""
    return list(_state.received)
