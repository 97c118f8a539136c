"""Host side of each transport: one adapter per transport on one template.

Layout
------
``base``
    :class:`~hilident.adapters.base.AdapterBase`, the template: the public run,
    upload and stop logic lives once; a transport supplies small protected hooks.
``backends``
    Which adapter serves which transport: the built-in table
    :data:`~hilident.adapters.backends.BACKENDS`, then the ``hilident.adapters``
    entry points of third-party packages (as python-can's ``BACKENDS`` and its
    ``can.interface`` entry points).
``events``
    The run events every transport reports.
``serial_board``
    The myRIO-style board on a serial line (COBS frames, PROTOCOL.md).
``canopen_drive``
    A CiA 402 drive on CANopen, composed of parts along its seams:
    ``canopen_sdo`` (object access), ``canopen_net`` (NMT, heartbeats,
    emergencies, the device-side net), ``canopen_mapping`` (mode, period, PDO
    and capture mapping), ``canopen_slots`` (filter slots); ``canopen_common``
    holds what the parts share. Its acquisition strategies are
    ``canopen_streamed``, ``canopen_buffered`` and ``canopen_recorder``;
    ``canopen_link`` opens the bus and ``canopen_trace`` writes CAN traces.
``modbus_drive``
    A Modbus drive (TCP or RTU), composed of ``modbus_requests`` (register
    requests, retries, exceptions, status), ``modbus_slots`` (filter slots) and
    ``modbus_capture`` (excitation table and capture); ``modbus_common`` holds
    what the parts share, among it ``ModbusAdapterState``, the adapter's
    attributes declared for the parts (the ``modbus_drive`` docstring says how
    the parts are typed).

A part is a class whose methods use only the adapter's attributes and the
other parts' methods; the adapter class lists the parts before
:class:`~hilident.adapters.base.AdapterBase`, so a part's method is the
adapter's method. Adapters never import :mod:`hilident.emulator`.
"""

from hilident.adapters.backends import BACKENDS, adapter_class, known_transports

__all__ = ["BACKENDS", "adapter_class", "known_transports"]
