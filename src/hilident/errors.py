"""Typed errors a user can cause.

The command line turns every :class:`HilidentError` into one line on stderr and a
non-zero exit code; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations


class HilidentError(Exception):
    """Base class of every error a user, a data file or a device can cause."""

    exit_code = 1


class ConfigError(HilidentError):
    """A configuration value is missing, of the wrong type or out of range.

    Parameters
    ----------
    key : str
        Dotted key of the offending value, e.g. ``"emulator.plant.m1"``.
    message : str
        What is wrong and what would be accepted.
    file : str, optional
        The configuration file the key was read from.
    """

    exit_code = 2

    def __init__(self, key: str, message: str, file: str | None = None):
        self.key = key
        self.message = message
        self.file = file
        where = f"{file}: " if file else ""
        super().__init__(f"{where}[{key}] {message}")


class UsageError(HilidentError):
    """A command-line argument cannot be used (an unwritable ``--out``, a bad ``--time-scale``)."""

    exit_code = 2


class ArmingRefused(HilidentError):
    """A run on a real port was not confirmed (no ``--yes``, no terminal, or the user said no); nothing moved."""

    exit_code = 2


class DataError(HilidentError):
    """Input arrays or recordings cannot be used (NaN, wrong length, unexciting, ...)."""

    exit_code = 3


class DeviceError(HilidentError):
    """The device or its link failed; the message names the port, object or register."""

    exit_code = 4
    #: The run's fault event this error ends the run with (set by ``AdapterBase.fault_error``), or None.
    event: dict | None = None


class ProtocolError(DeviceError):
    """A frame or message on the wire violates the protocol."""


class LimitTrip(DeviceError):
    """A configured safety limit (torque, velocity, position) was crossed and the axis stopped."""

    exit_code = 5


class Interrupted(KeyboardInterrupt):
    """The session was ended by a signal (Ctrl-C, SIGTERM, SIGHUP).

    A :class:`KeyboardInterrupt`, so no ``except Exception`` swallows it and every
    path that stops the axis on Ctrl-C does the same for the other signals.

    Parameters
    ----------
    signum : int
        The signal that ended the session; the exit code is ``128 + signum``
        (SIGINT 130, SIGHUP 129, SIGTERM 143), as a shell reports it.
    """

    def __init__(self, signum: int):
        import signal as _signal

        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        try:
            name = _signal.Signals(self.signum).name
        except ValueError:
            name = f"signal {self.signum}"
        super().__init__(f"interrupted by {name}")
