"""Where a device can be reached: the serial ports and CAN interfaces this machine has, and why a port did not open.

:func:`serial_ports` and :func:`can_interfaces` feed ``hilident ports``;
:func:`open_failure` turns the ``OSError`` (or ``serial.SerialException``)
of a port that would not open into a :class:`~hilident.errors.DeviceError`
naming ``[device].port`` and the likely cause, for every transport that opens
a serial line or a CAN channel.
"""

from __future__ import annotations

import errno
import logging
import re
import sys
import threading
from dataclasses import dataclass

from hilident.errors import DeviceError

log = logging.getLogger(__name__)

#: python-can interfaces that answer ``detect_available_configs`` from the local machine at once (no network
#: discovery, no vendor driver that may hang while probing).
FAST_CAN_INTERFACES = ("socketcan", "pcan", "kvaser", "vector", "ixxat", "slcan", "gs_usb")
#: How long ``hilident ports`` waits for python-can's detection in all, s.
CAN_DETECT_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class SerialPort:
    """One serial port as pyserial lists it."""

    device: str  # what goes into [device].port: /dev/ttyUSB0, COM3, ...
    description: str
    hwid: str  # USB VID:PID and serial number, or what the OS knows


@dataclass(frozen=True)
class CanChannel:
    """One CAN channel python-can detects: ``[device.canopen] can_interface`` and ``[device].port``."""

    interface: str
    channel: str


def serial_ports() -> list[SerialPort]:
    """The serial ports pyserial finds (``serial.tools.list_ports.comports()``), sorted by device name."""
    from serial.tools import list_ports

    found = [SerialPort(str(p.device), str(p.description or ""), str(p.hwid or "")) for p in list_ports.comports()]
    return sorted(found, key=lambda p: p.device)


def can_interfaces(
    interfaces=FAST_CAN_INTERFACES, timeout_s: float = CAN_DETECT_TIMEOUT_S
) -> tuple[list[CanChannel], list[str]]:
    """The CAN channels python-can detects on ``interfaces`` (``can.detect_available_configs``).

    Each interface is asked on its own: one that raises (a vendor library
    missing, a driver refusing) is left out with a note, and the whole search
    stops after ``timeout_s`` seconds (the interfaces not answered by then are
    noted, not waited for).

    Returns
    -------
    channels : list of CanChannel
    notes : list of str
        One line per interface that could not be asked.
    """
    channels: list[CanChannel] = []
    notes: list[str] = []
    lock = threading.Lock()

    def ask() -> None:
        can_log = logging.getLogger("can")
        level = can_log.level
        if not logging.getLogger().handlers:  # no --log-level: a missing vendor library is no news here
            can_log.setLevel(logging.ERROR)
        try:
            ask_each()
        finally:
            can_log.setLevel(level)

    def ask_each() -> None:
        try:
            import can
        except ImportError as exc:  # pragma: no cover - a dependency
            with lock:
                notes.append(f"python-can not importable: {exc}")
            return
        for name in interfaces:
            try:
                configs = can.detect_available_configs(interfaces=[name])
                log.debug("python-can %s: %d channel(s)", name, len(configs))
            except Exception as exc:  # an interface's own failure must not hide the others
                log.debug("python-can %s: detection failed", name, exc_info=True)
                with lock:
                    notes.append(f"{name}: not asked ({type(exc).__name__}: {exc})")
                continue
            with lock:
                channels.extend(CanChannel(str(c.get("interface", name)), str(c.get("channel", ""))) for c in configs)
                asked.append(name)

    asked: list[str] = []
    worker = threading.Thread(target=ask, name="hilident-can-detect", daemon=True)
    worker.start()
    worker.join(timeout_s)
    with lock:
        result, found_notes = list(channels), list(notes)
        if worker.is_alive():
            left = [n for n in interfaces if n not in asked and not any(x.startswith(f"{n}:") for x in notes)]
            found_notes.append(f"no answer within {timeout_s:g} s from: {', '.join(left)}")
    return result, found_notes


def describe_ports(serial_list: list[SerialPort], can_list: list[CanChannel], notes: list[str]) -> str:
    """The text ``hilident ports`` prints: one line per port, with what to write in the config."""
    lines = ["serial ports ([device] port = ...):"]
    if serial_list:
        lines += [f"  {p.device}\t{p.description or '-'}\t{p.hwid or '-'}" for p in serial_list]
    else:
        lines.append("  none found")
    lines.append("CAN channels ([device.canopen] can_interface = ..., [device] port = ...):")
    if can_list:
        lines += [f"  {c.interface}\t{c.channel}" for c in can_list]
    else:
        lines.append("  none found")
    lines += [f"  note: {n}" for n in notes]
    return "\n".join(lines)


# --- a port that does not open -------------------------------------------------------------------------------

_GROUP_HINT = (
    "permission denied: add yourself to the group that owns the port (usually dialout: "
    "sudo usermod -aG dialout $USER, then log out and in again)"
)
_MISSING_HINT = (
    "no such device: check the name (hilident ports lists the serial ports and CAN channels found) "
    "and that the device is plugged in and powered"
)
_BUSY_HINT = (
    "the port is in use by another program (a serial terminal, ModemManager, another hilident session): "
    "close it and try again"
)


def _errno_of(exc: BaseException) -> int | None:
    """The errno behind ``exc``: its own, its cause's, or the ``[Errno N]`` pyserial writes into its message."""
    for e in (exc, exc.__cause__, exc.__context__):
        code = getattr(e, "errno", None)
        if isinstance(code, int):
            return code
    m = re.search(r"\[Errno (\d+)\]", str(exc))
    return int(m.group(1)) if m else None


def open_hint(exc: BaseException) -> str:
    """What most likely kept a port from opening, as advice; empty when the error says nothing recognisable."""
    code = _errno_of(exc)
    text = str(exc).lower()
    if code in (errno.EACCES, errno.EPERM) or "permission denied" in text or "access is denied" in text:
        return _GROUP_HINT if sys.platform != "win32" else "access denied: the port is in use by another program"
    if code == errno.EBUSY or "busy" in text or "in use" in text or "lock" in text:
        return _BUSY_HINT
    if (
        code in (errno.ENOENT, errno.ENXIO, errno.ENODEV)
        or "no such" in text
        or "cannot find" in text
        or "filenotfound" in text
        or "could not find" in text
    ):
        return _MISSING_HINT
    return ""


def open_failure(port: str, exc: BaseException, what: str = "cannot open", key: str = "device.port") -> DeviceError:
    """A :class:`DeviceError` for a port that would not open: ``[device].port``, the port, the cause and a hint.

    Parameters
    ----------
    port : str
        The port as configured.
    exc : BaseException
        What the opening raised (``OSError``, ``serial.SerialException``,
        ``can.CanError``, ...).
    what : str
        What was being done, e.g. ``"cannot open at 115200 baud"``.
    key : str
        The configuration key the port came from.

    Examples
    --------
    >>> import errno
    >>> message = str(open_failure("/dev/ttyUSB0", PermissionError(errno.EACCES, "Permission denied")))
    >>> message.split("; ")[0]
    "[device.port] '/dev/ttyUSB0': cannot open: [Errno 13] Permission denied"
    >>> "dialout" in message
    True
    """
    log.debug("%s: %s", port, what, exc_info=exc)
    detail = str(exc) or type(exc).__name__
    hint = open_hint(exc)
    return DeviceError(f"[{key}] {port!r}: {what}: {detail}" + (f"; {hint}" if hint else ""))
