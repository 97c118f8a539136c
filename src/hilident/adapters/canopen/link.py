"""Opening the CAN bus a CANopen drive hangs on, and tracing it.

``[device]`` names the bus the python-can way: ``[device.canopen] can_interface``
(socketcan, pcan, kvaser, ixxat, vector, slcan, socketcand, virtual, ...) and ``port``, the
interface's channel (``can0``, ``PCAN_USBBUS1``, ``0``, a virtual channel name).
For ``socketcand`` the port is ``"HOST:PORT/CHANNEL"``, e.g.
``"127.0.0.1:29536/can0"``: the daemon's address and the bus it serves.

:class:`TracingNetwork` and :class:`FrameTrace` (the CAN trace of a run) live in
:mod:`hilident.adapters.canopen.trace` and are re-exported here.
"""

from __future__ import annotations

import logging

import can

from hilident.adapters.canopen.trace import FrameTrace, TracingNetwork
from hilident.adapters.ports import open_failure
from hilident.config.tables import DeviceConfig
from hilident.errors import ConfigError

log = logging.getLogger(__name__)

__all__ = ["bus_arguments", "parse_socketcand_port", "open_network", "TracingNetwork", "FrameTrace"]


def parse_socketcand_port(port: str) -> tuple[str, int, str]:
    """``"HOST:PORT/CHANNEL"`` -> (host, port, channel).

    Raises
    ------
    ConfigError
        ``port`` is not of that form (the message names ``device.port``).
    """
    address, slash, channel = port.partition("/")
    host, colon, number = address.rpartition(":")
    if not (slash and colon and host and channel and number.isdigit() and 0 < int(number) < 65536):
        raise ConfigError(
            "device.port", f'socketcand needs "HOST:PORT/CHANNEL" (e.g. "127.0.0.1:29536/can0"), got {port!r}'
        )
    return host, int(number), channel


class _BusGoneFilter(logging.Filter):
    """Drops python-can's traceback when a cyclic send (the host's heartbeat) fails because the bus went away.

    The task stops on that error by design; the run notices the lost bus itself
    and reports it as one :class:`DeviceError` naming the interface and channel.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not isinstance(exc, (can.CanError, OSError))


_BUS_GONE = _BusGoneFilter()


class _OwnAbortFilter(logging.Filter):
    """Drops canopen's log lines about SDO transfers the host itself broke off.

    The adapter aborts a block transfer a signal interrupted (and canopen's
    client aborts one that failed); what the user needs is the one-line error
    or the interruption, not the library's account of the abort.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(("Transfer aborted by client", "Block transfer was not finished"))


_OWN_ABORT = _OwnAbortFilter()


def bus_arguments(device: DeviceConfig, default_bitrate: int) -> dict:
    """Keyword arguments of :class:`can.Bus` for ``[device]``."""
    interface = device.canopen.can_interface
    kwargs = {"interface": interface, "bitrate": device.baudrate or default_bitrate}
    if interface == "socketcand":
        host, port, channel = parse_socketcand_port(device.port)
        kwargs.update(channel=channel, host=host, port=port, tcp_tune=True)
        # its client warns each time TCP splits a frame line, which is routine: keep real errors only
        logging.getLogger("can.interfaces.socketcand.socketcand").setLevel(logging.ERROR)
    else:
        kwargs["channel"] = device.port
    if interface == "virtual":
        kwargs["receive_own_messages"] = False
    return kwargs


def open_network(device: DeviceConfig, default_bitrate: int, label: str) -> TracingNetwork:
    """Connect to the bus ``[device]`` names.

    Raises
    ------
    DeviceError
        The interface is unknown or the channel cannot be opened; the message
        names ``label`` (interface and port).
    ConfigError
        A malformed socketcand port.
    """
    kwargs = bus_arguments(device, default_bitrate)
    cyclic_log = logging.getLogger("can.bcm")  # python-can's cyclic send tasks
    if _BUS_GONE not in cyclic_log.filters:
        cyclic_log.addFilter(_BUS_GONE)
    sdo_log = logging.getLogger("canopen.sdo.client")
    if _OWN_ABORT not in sdo_log.filters:
        sdo_log.addFilter(_OWN_ABORT)
    network = TracingNetwork()
    log.debug("opening the CAN bus: %s", kwargs)
    try:
        network.connect(**kwargs)
    except (can.CanError, OSError, ValueError, TypeError, ImportError, NotImplementedError, TimeoutError) as exc:
        raise open_failure(
            device.port, exc, f"{label}: cannot open CAN interface {device.canopen.can_interface!r}"
        ) from None
    return network
