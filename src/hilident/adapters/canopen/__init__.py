"""The host side of a CiA 402 drive on CANopen: one adapter and the parts it owns.

:class:`~hilident.adapters.canopen.drive.CanopenDriveAdapter` (``drive``) opens
the drive, brings it to a known state, runs the CiA 402 state machine and fills
in the hooks of :class:`~hilident.adapters.base.AdapterBase`. It owns:

``adapter.sdo`` (``sdo``, :class:`~hilident.adapters.canopen.sdo.SdoAccess`)
    every object read and write, block transfers, aborts named;
``adapter.net`` (``net``, :class:`~hilident.adapters.canopen.net.NetWatch`)
    NMT commands, the host's heartbeat (``net.heartbeat``,
    :class:`~hilident.adapters.canopen.net.HostHeartbeat`) and the drive's
    consumer watching it, the drive's heartbeat or node guarding, emergencies;
``adapter.mapping`` (``mapping``, :class:`~hilident.adapters.canopen.mapping.ChannelMapping`)
    limits, sample period, channel codecs and the PDO or capture mapping; it
    returns the run's :class:`~hilident.adapters.canopen.common.RunLayout`,
    which the adapter keeps as ``adapter.layout``;
``adapter.slots`` (``slots``, :class:`~hilident.adapters.canopen.slots.CanopenFilterSlots`)
    the filter slots and storing parameters in non-volatile memory.

Each part is given what it needs when the adapter makes it (the SDO part, the
description, the port, ...) and never sees the adapter. ``common`` holds the
constants and the frozen values the parts share. A run is played by one of the
acquisition strategies ``streamed``, ``buffered``, ``recorder``; they see the
adapter through :class:`~hilident.adapters.canopen.streamed.DriveHost`.
``link`` opens the bus, ``trace`` writes CAN traces.

May import ``protocol``, ``drivers``, ``events``; never ``emulator``.
"""
