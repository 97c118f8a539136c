"""The host side of a Modbus drive (TCP or RTU): one adapter and the parts it owns.

:class:`~hilident.adapters.modbus.drive.ModbusDriveAdapter` (``drive``) opens
the drive, brings it to a known state, identifies it, follows a run by the
drive's status and fills in the hooks of
:class:`~hilident.adapters.base.AdapterBase`. It owns:

``adapter.registers`` (``requests``, :class:`~hilident.adapters.modbus.requests.RegisterAccess`)
    every request, its retries, stale answers and exception answers, and the
    status registers;
``adapter.capture`` (``capture``, :class:`~hilident.adapters.modbus.capture.TableCapture`)
    the excitation table through its page window, the trigger, the capture
    read back; its record layout (``capture.layout``) is set by ``configure()``;
``adapter.slots`` (``slots``, :class:`~hilident.adapters.modbus.slots.ModbusFilterSlots`)
    filter slots as register blocks or as a parameter drive's notch
    parameters.

The capture and slot parts send their requests through ``registers``; none of
the parts sees the adapter. ``common`` holds the constants, the RTU client and
the frozen values the parts share.

May import ``protocol``, ``drivers``, ``events``; never ``emulator``.
"""
