"""One session per device: a lock file keyed by the resolved port (and node), held while a session runs.

Two hosts on one line corrupt each other's runs (on a pseudo-terminal one of
them dies and the other's run is stopped by the first one's STOP; on TCP the
second client takes the drive over). A session therefore takes an exclusive
``flock`` on a file named after the device before it opens it. The kernel
drops the lock when the holding process dies, however it dies, so a lock left
by a killed session is recovered by the next one; the file keeps the holder's
pid so a refused session can name it.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import socket
import tempfile
from pathlib import Path
from urllib.parse import urlsplit

from hilident.errors import DeviceError

try:  # POSIX; on Windows the OS already refuses a second open of a COM port
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]  # the module or None: checked before use


def lock_folder() -> Path:
    """Where the lock files live: ``$HILIDENT_LOCK_DIR``, else ``<tmp>/hilident-locks``."""
    return Path(os.environ.get("HILIDENT_LOCK_DIR") or Path(tempfile.gettempdir()) / "hilident-locks")


def _resolve_host(host: str) -> str:
    try:
        return socket.gethostbyname(host)
    except OSError:
        return host.lower()


def device_key(
    transport: str, port: str, *, node_id: int | None = None, device_id: int | None = None, can_interface: str = ""
) -> str:
    """A name for the device that two configs reaching the same device share.

    Parameters
    ----------
    transport : {"serial", "modbus", "canopen"}
    port : str
        A device path (symlinks resolved), a URL (``socket://``, ``tcp://``,
        ``rfc2217://``; the host name resolved) or a CAN channel.
    node_id, device_id : int, optional
        CANopen node, Modbus TCP unit id (an RTU line takes one master whatever
        the id, so it is keyed by the line alone).
    can_interface : str
        The python-can interface of a CANopen bus.
    """
    if transport == "canopen":
        return f"canopen:{can_interface}:{port}:node{node_id}"
    parts = urlsplit(port)
    if parts.scheme and parts.netloc:
        where = f"{parts.scheme}://{_resolve_host(parts.hostname or '')}:{parts.port}"
        if transport == "modbus" and parts.scheme == "tcp":
            where += f":unit{device_id}"
        return f"{transport}:{where}"
    windows_port = re.match(r"^COM\d+$", port, re.I)
    return "line:" + (port.upper() if windows_port else os.path.realpath(port))


class DeviceLock:
    """An exclusive, process-lifetime lock on one device.

    Examples
    --------
    >>> with DeviceLock(device_key("serial", "/dev/ttyUSB0")):  # doctest: +SKIP
    ...     run_the_session()
    """

    def __init__(self, key: str, folder: Path | None = None):
        self.key = key
        digest = hashlib.sha1(key.encode()).hexdigest()[:16]
        self.path = (folder or lock_folder()) / f"{digest}.lock"
        self._fd: int | None = None
        self.recovered_from: int | None = None  # pid of a dead holder whose lock was taken over

    def acquire(self) -> DeviceLock:
        """Take the lock, or raise :class:`DeviceError` naming the pid that holds it."""
        if fcntl is None:  # pragma: no cover
            return self
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(OSError):
                os.chmod(self.path.parent, 0o1777)  # shared by every user of the bench machine
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise DeviceError(f"{self.key}: cannot create the device lock {self.path}: {exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _read_pid(fd)
            os.close(fd)
            raise DeviceError(
                f"[device.port] {self.key}: in use by another hilident session (pid {holder if holder else 'unknown'}"
                f"); one session per device (lock {self.path})"
            ) from None
        previous = _read_pid(fd)
        if previous and previous != os.getpid():
            self.recovered_from = previous  # its holder died without releasing: the kernel dropped the flock
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n{self.key}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Let the next session have the device. Never raises."""
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.ftruncate(self._fd, 0)
        with contextlib.suppress(OSError):
            os.close(self._fd)  # closing drops the flock
        self._fd = None

    def __enter__(self) -> DeviceLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read_pid(fd: int) -> int | None:
    try:
        text = os.pread(fd, 64, 0).decode(errors="replace").split("\n", 1)[0].strip()
        return int(text) if text else None
    except (OSError, ValueError):
        return None


class DeviceLocks:
    """The locks of several devices a session drives together (the nodes of one CANopen bus), taken in order
    and released together; a lock that cannot be taken releases the ones taken before it."""

    def __init__(self, keys: list[str], folder: Path | None = None):
        self.locks = [DeviceLock(key, folder) for key in keys]
        self.recovered_from: int | None = None  # pid of a dead holder of one of the locks

    def acquire(self) -> DeviceLocks:
        """Take every lock, or raise the :class:`DeviceError` of the first one held elsewhere."""
        try:
            for lock in self.locks:
                lock.acquire()
                self.recovered_from = self.recovered_from or lock.recovered_from
        except BaseException:
            self.release()
            raise
        return self

    def release(self) -> None:
        """Every lock released. Never raises."""
        for lock in self.locks:
            lock.release()
