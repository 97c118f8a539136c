"""Wire formats, shared by the host adapters and the emulated twins: pure, no sockets, no clocks.

- ``framing``, ``serial_board``: the serial board protocol (COBS frames with CRC-32, its messages)
- ``cia402``, ``emcy_codes``: the CiA 402 power state machine, mode codes and emergency codes
- ``canopen_types``: the small values the CANopen modules share (object addresses, mode specs)
- ``canopen_profile``, ``canopen_objects``, ``canopen_recorder``, ``eds``: a CANopen drive as its EDS and
  ``driver.toml`` describe it (standard and vendor objects, drive-side generator and recorder)
- ``modbus/``: a Modbus drive's register map (``register_map``, read by ``map_parser``), its value encodings
  (``codecs``), paged windows (``paging``), filter slots, RTU framing and exception codes
- ``filter_encoding``: how a drive stores a notch in one filter slot

Import from the modules; this package re-exports nothing.

May import ``filters``, ``errors`` and the schema mechanism (``config.schema``); no I/O, never ``adapters`` or
``emulator`` (they meet here).
"""

__all__: list[str] = []
