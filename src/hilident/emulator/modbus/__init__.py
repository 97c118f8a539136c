"""The Modbus drives' twin: :mod:`.firmware` and :mod:`.parameter_firmware` (registers), :mod:`.pdu`, :mod:`.rtu`
and :mod:`.server` (the wire)."""
