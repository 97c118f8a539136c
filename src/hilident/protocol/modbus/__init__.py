"""A Modbus drive's wire format, shared by the host adapter and the emulated twin: pure, no sockets, no clocks.

- :mod:`.codecs`: how values sit in 16-bit registers (integers, floats, text; word and byte order)
- :mod:`.registers`: one named register of a map, and the rule that turns vendor parameter codes into addresses
- :mod:`.paging`: the paged windows onto the excitation table and the capture buffer, the transfer chunks
  through them, the table's CRC
- :mod:`.filter_slots`: where a drive keeps its filter slots
- :mod:`.map_parser`: the ``[modbus]`` tables of a driver description, validated
- :mod:`.loop_registers`: the ``[loop]`` table, each cascade parameter in a register of the map
- :mod:`.register_map`: :class:`~hilident.protocol.modbus.register_map.RegisterMap`, a drive's whole map, built
  from those tables
- :mod:`.rtu`: what a serial line adds: the CRC that ends an RTU frame, counting frames
- :mod:`.exception_codes`: what a Modbus exception code means

Import from the modules; this package re-exports nothing.
"""

__all__: list[str] = []
