"""Host side of each transport: one adapter per transport on one template.

Layout
------
``base``
    :class:`~hilident.adapters.base.AdapterBase`, the template in the style of
    python-can's ``BusABC``: the public run, upload and stop logic lives once
    and no adapter overrides it; a transport supplies small protected hooks
    (``_play``, ``_command_safe``, ``_release``, ``_read_filter``, ...).
``backends``
    Which adapter serves which transport: the built-in table
    :data:`~hilident.adapters.backends.BACKENDS`, then the ``hilident.adapters``
    entry points of third-party packages (as python-can's ``BACKENDS`` and its
    ``can.interface`` entry points); :func:`~hilident.adapters.backends.adapter_class`
    resolves a transport name.
``ports``
    The ports and CAN interfaces a machine offers, and the words for a port
    that cannot be opened.
``serial``
    The myRIO-style board on a serial line (COBS frames, PROTOCOL.md):
    ``serial.board``.
``canopen``
    A CiA 402 drive on CANopen: the adapter (``canopen.drive``) and the parts
    it owns (see :mod:`hilident.adapters.canopen`), its acquisition strategies
    (``streamed``, ``buffered``, ``recorder``), the bus (``link``) and CAN
    traces (``trace``).
``modbus``
    A Modbus drive (TCP or RTU): the adapter (``modbus.drive``) and the parts
    it owns (see :mod:`hilident.adapters.modbus`).

A transport's parts are objects its adapter owns (``adapter.sdo``,
``adapter.registers``, ``adapter.slots``, ...), each given what it needs when
it is made; a call site names the part the code lives in. Parts never see the
adapter; the adapter implements the template's hooks by handing the work to
them. The run events every transport reports are :mod:`hilident.events`.
Adapters never import :mod:`hilident.emulator`.

May import ``protocol``, ``filters``, ``drivers``, ``config``, ``events``, ``units``, ``endings`` and ``links``;
never ``emulator``, ``session``, ``batch`` or ``cli``. Import a name from the module that defines it (the package
re-exports nothing).
"""
